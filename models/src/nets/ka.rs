//! The K_A regressor of Zimenko, Afanasev, Kolesnikov (2022): three dense layers
//! (ReLU, ReLU, sigmoid) feeding one linear output, trained with Adam on min–max
//! scaled data. Weights are initialised from the fdmlab seed (not burn's global RNG)
//! so the same seed gives the same network on any thread.

use crate::ModelError;
use burn::module::{Param, ParamId};
use burn::nn::Linear;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::activation::{relu, sigmoid};
use rand::seq::SliceRandom;
use rand::Rng as _;
use serde::{Deserialize, Serialize};

/// Layer widths of the network.
#[derive(Config, Debug, PartialEq)]
pub struct KaNetConfig {
    /// Number of (scaled, one-hot expanded) input features.
    pub inputs: usize,
    #[config(default = 32)]
    pub hidden1: usize,
    #[config(default = 32)]
    pub hidden2: usize,
    #[config(default = 16)]
    pub hidden3: usize,
}

/// The network: `out(sigmoid(l3(relu(l2(relu(l1(x)))))))`.
#[derive(Module, Debug)]
pub struct KaNet {
    pub l1: Linear,
    pub l2: Linear,
    pub l3: Linear,
    pub out: Linear,
}

/// Plain weights of one dense layer: `y = x·W + b`, `w` row-major `[inputs][outputs]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DenseWeights {
    pub inputs: usize,
    pub outputs: usize,
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

/// All weights of a [`KaNet`], in forward order (activations relu, relu, sigmoid, none).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetWeights {
    pub layers: Vec<DenseWeights>,
}

impl KaNetConfig {
    /// Reject widths that make no network.
    pub fn check(&self) -> Result<(), ModelError> {
        for (name, v) in [("inputs", self.inputs), ("hidden1", self.hidden1), ("hidden2", self.hidden2), ("hidden3", self.hidden3)] {
            if v == 0 || v > 4096 {
                return Err(ModelError::invalid(name, v, "layer width must be within 1–4096"));
            }
        }
        Ok(())
    }

    fn widths(&self) -> [usize; 5] {
        [self.inputs, self.hidden1, self.hidden2, self.hidden3, 1]
    }

    /// Build the network with PyTorch-default uniform(±1/√fan_in) weights drawn from `seed`.
    pub fn init_seeded(&self, device: &Device, seed: u64) -> Result<KaNet, ModelError> {
        self.check()?;
        let mut rng = crate::rng::seeded(seed, 0x6b61);
        let w = self.widths();
        let layers: Vec<DenseWeights> = (0..4)
            .map(|i| {
                let bound = 1.0 / (w[i] as f32).sqrt();
                let mut draw = |n: usize| (0..n).map(|_| rng.random_range(-bound..bound)).collect::<Vec<f32>>();
                let wv = draw(w[i] * w[i + 1]);
                let bv = draw(w[i + 1]);
                DenseWeights { inputs: w[i], outputs: w[i + 1], w: wv, b: bv }
            })
            .collect();
        KaNet::from_weights(&NetWeights { layers }, device)
    }
}

fn dense(d: &DenseWeights, id: u64, device: &Device) -> Result<Linear, ModelError> {
    if d.w.len() != d.inputs * d.outputs || d.b.len() != d.outputs {
        return Err(ModelError::Shape(format!("dense layer {id}: {}×{} weights, {} biases", d.inputs, d.outputs, d.b.len())));
    }
    let w = Tensor::<2>::from_data(TensorData::new(d.w.clone(), [d.inputs, d.outputs]), device);
    let b = Tensor::<1>::from_data(TensorData::new(d.b.clone(), [d.outputs]), device);
    Ok(Linear {
        weight: Param::initialized(ParamId::from(2 * id), w.require_grad_if(device)),
        bias: Some(Param::initialized(ParamId::from(2 * id + 1), b.require_grad_if(device))),
    })
}

/// Mark parameters trainable only on an autodiff device.
trait RequireGradIf {
    fn require_grad_if(self, device: &Device) -> Self;
}
impl<const D: usize> RequireGradIf for Tensor<D> {
    fn require_grad_if(self, device: &Device) -> Self {
        if device.is_autodiff() {
            self.require_grad()
        } else {
            self
        }
    }
}

fn weights_of(l: &Linear) -> Result<DenseWeights, ModelError> {
    let [inputs, outputs] = l.weight.shape().dims();
    let w = l.weight.val().into_data().try_into_vec::<f32>().map_err(|e| ModelError::Numerical(format!("{e:?}")))?;
    let b = match &l.bias {
        Some(b) => b.val().into_data().try_into_vec::<f32>().map_err(|e| ModelError::Numerical(format!("{e:?}")))?,
        None => vec![0.0; outputs],
    };
    Ok(DenseWeights { inputs, outputs, w, b })
}

impl KaNet {
    /// Rebuild a network from plain weights (4 layers with chained widths, one output).
    pub fn from_weights(weights: &NetWeights, device: &Device) -> Result<KaNet, ModelError> {
        let l = &weights.layers;
        if l.len() != 4 || l.windows(2).any(|p| p[0].outputs != p[1].inputs) || l[3].outputs != 1 {
            return Err(ModelError::Shape("expected 4 chained dense layers ending in one output".into()));
        }
        Ok(KaNet { l1: dense(&l[0], 0, device)?, l2: dense(&l[1], 1, device)?, l3: dense(&l[2], 2, device)?, out: dense(&l[3], 3, device)? })
    }

    /// Plain weights, for artifacts and exports.
    pub fn weights(&self) -> Result<NetWeights, ModelError> {
        Ok(NetWeights { layers: vec![weights_of(&self.l1)?, weights_of(&self.l2)?, weights_of(&self.l3)?, weights_of(&self.out)?] })
    }

    /// The network in burn's native Burnpack format (`.bpk`), for burn programs
    /// that load it with `BurnpackStore` (tensor paths `l1.weight`, …, `out.bias`).
    pub fn to_burnpack(&self) -> Result<Vec<u8>, ModelError> {
        let mut store = BurnpackStore::from_bytes(None);
        self.save_into(&mut store).map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?;
        Ok(store.get_bytes().map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?.to_vec())
    }

    /// Load a network of the given widths from Burnpack bytes.
    pub fn from_burnpack(bytes: &[u8], config: &KaNetConfig, device: &Device) -> Result<KaNet, ModelError> {
        let mut net = config.init_seeded(device, 0)?;
        let mut store = BurnpackStore::from_bytes(Some(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec())));
        net.load_from(&mut store).map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?;
        Ok(net)
    }

    /// Forward pass on a batch `[rows, inputs]` → `[rows, 1]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let h = relu(self.l1.forward(x));
        let h = relu(self.l2.forward(h));
        let h = sigmoid(self.l3.forward(h));
        self.out.forward(h)
    }

    /// Predict scaled targets for row-major scaled inputs (`inputs` columns).
    pub fn predict(&self, x: &[f32], inputs: usize) -> Result<Vec<f32>, ModelError> {
        if inputs == 0 || x.len() % inputs != 0 {
            return Err(ModelError::Shape(format!("{} values are not rows of {inputs}", x.len())));
        }
        let device = self.l1.weight.val().device();
        let t = Tensor::<2>::from_data(TensorData::new(x.to_vec(), [x.len() / inputs, inputs]), &device);
        self.forward(t).into_data().try_into_vec::<f32>().map_err(|e| ModelError::Numerical(format!("{e:?}")))
    }
}

/// Optimisation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub epochs: usize,
    /// Mini-batch rows (the whole set when larger than it).
    pub batch_size: usize,
    /// Adam's initial learning rate; decays along a half cosine to 1/50 of it.
    pub learning_rate: f64,
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig { epochs: 500, batch_size: 128, learning_rate: 0.01, seed: 7 }
    }
}

impl TrainConfig {
    /// Reject settings that cannot train.
    pub fn check(&self) -> Result<(), ModelError> {
        if self.epochs == 0 || self.epochs > 1_000_000 {
            return Err(ModelError::invalid("epochs", self.epochs, "must be within 1–1000000"));
        }
        if self.batch_size == 0 {
            return Err(ModelError::invalid("batch_size", 0, "must be positive"));
        }
        if !(self.learning_rate > 0.0 && self.learning_rate < 10.0) {
            return Err(ModelError::invalid("learning_rate", self.learning_rate, "must be within (0, 10)"));
        }
        Ok(())
    }
}

/// Train a network on row-major scaled inputs `x` (`inputs` columns) and scaled
/// targets `y` with MSE loss and Adam (Kingma & Ba 2015); returns the inference copy
/// (`valid()`, no autodiff) on the flex device.
pub fn train(cfg: &KaNetConfig, tc: &TrainConfig, x: &[f32], y: &[f32]) -> Result<KaNet, ModelError> {
    cfg.check()?;
    tc.check()?;
    let d = cfg.inputs;
    let n = y.len();
    if n == 0 || x.len() != n * d {
        return Err(ModelError::Shape(format!("{} inputs for {n} rows of {d} features", x.len())));
    }
    let device = Device::flex().autodiff();
    let mut model = cfg.init_seeded(&device, tc.seed)?;
    let mut optim = AdamConfig::new().init();
    let mut rng = crate::rng::seeded(tc.seed, 0x7472);
    let mut order: Vec<usize> = (0..n).collect();
    let bs = tc.batch_size.min(n);
    let (mut xb, mut yb) = (Vec::with_capacity(bs * d), Vec::with_capacity(bs));
    for epoch in 0..tc.epochs {
        let progress = epoch as f64 / tc.epochs as f64;
        let lr = tc.learning_rate * (0.02 + 0.98 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos()));
        order.shuffle(&mut rng);
        for batch in order.chunks(bs) {
            xb.clear();
            yb.clear();
            for &i in batch {
                xb.extend_from_slice(&x[i * d..(i + 1) * d]);
                yb.push(y[i]);
            }
            let xt = Tensor::<2>::from_data(TensorData::new(xb.clone(), [batch.len(), d]), &device);
            let yt = Tensor::<2>::from_data(TensorData::new(yb.clone(), [batch.len(), 1]), &device);
            let loss = (model.forward(xt) - yt).square().mean();
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            model = optim.step(lr, model, grads);
        }
    }
    Ok(model.valid())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_round_trip_and_seed_determinism() {
        let cfg = KaNetConfig::new(3);
        let dev = Device::flex();
        let a = cfg.init_seeded(&dev, 5).and_then(|n| n.weights());
        let b = cfg.init_seeded(&dev, 5).and_then(|n| n.weights());
        assert!(a.is_ok());
        assert_eq!(a, b);
        let w = a.unwrap_or(NetWeights { layers: vec![] });
        let back = KaNet::from_weights(&w, &dev).and_then(|n| n.weights());
        assert_eq!(back.ok(), Some(w));
    }

    #[test]
    fn burnpack_round_trip_is_exact_and_deterministic() {
        let cfg = KaNetConfig::new(4).with_hidden1(8).with_hidden2(6).with_hidden3(5);
        let dev = Device::flex();
        let net = cfg.init_seeded(&dev, 11).expect("net");
        let bytes = net.to_burnpack().expect("save");
        // The same weights give the same bytes (artifacts are content-addressed).
        assert_eq!(bytes, cfg.init_seeded(&dev, 11).and_then(|n| n.to_burnpack()).expect("save again"));
        let back = KaNet::from_burnpack(&bytes, &cfg, &dev).expect("load");
        assert_eq!(back.weights().expect("w"), net.weights().expect("w"));
        // A network of other widths refuses the file instead of loading garbage.
        assert!(KaNet::from_burnpack(&bytes, &KaNetConfig::new(4), &dev).is_err());
    }

    #[test]
    fn learns_a_smooth_function() {
        // y = 0.2 + 0.5·x0·x1 on [0,1]²: 400 points, 300 epochs. A 32-32-16 net fits this
        // to well under 0.02 RMS; the bound is loose to stay robust to float ordering.
        let mut rng = crate::rng::seeded(3, 0);
        let (mut x, mut y) = (vec![], vec![]);
        for _ in 0..400 {
            let (a, b): (f32, f32) = (rng.random(), rng.random());
            x.extend([a, b]);
            y.push(0.2 + 0.5 * a * b);
        }
        let tc = TrainConfig { epochs: 300, batch_size: 64, learning_rate: 0.01, seed: 1 };
        let net = train(&KaNetConfig::new(2), &tc, &x, &y);
        let p = net.and_then(|n| n.predict(&x, 2)).unwrap_or_default();
        assert_eq!(p.len(), 400);
        let rms = (p.iter().zip(&y).map(|(a, b)| (a - b).powi(2)).sum::<f32>() / 400.0).sqrt();
        assert!(rms < 0.02, "rms {rms}");
        // Same seed, same data: bit-identical network.
        let again = train(&KaNetConfig::new(2), &tc, &x, &y).and_then(|n| n.predict(&x, 2)).unwrap_or_default();
        assert_eq!(p, again);
    }
}
