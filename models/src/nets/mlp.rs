//! The one multilayer perceptron of fdmlab: dense layers with a fixed
//! activation after each, weights drawn from the fdmlab seed (not burn's global
//! RNG, so the same seed gives the same network on any thread), plain-weight and
//! Burnpack round trips. The K_A regressor and the turn predictor are both this
//! module with their own widths and activations.

use crate::ModelError;
use burn::module::{Param, ParamId};
use burn::nn::Linear;
use burn::prelude::*;
use burn::store::{BurnpackStore, KeyRemapper, ModuleAdapter, ModuleContext, ModuleSnapshot};
use burn::tensor::activation::{relu, sigmoid};
use rand::Rng as _;
use serde::{Deserialize, Serialize};

/// Activation applied after a dense layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Activation {
    Relu,
    Sigmoid,
    /// No activation (output layers).
    Identity,
}

/// Plain weights of one dense layer: `y = x·W + b`, `w` row-major `[inputs][outputs]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DenseWeights {
    pub inputs: usize,
    pub outputs: usize,
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

/// All weights of an [`Mlp`], in forward order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetWeights {
    pub layers: Vec<DenseWeights>,
}

impl NetWeights {
    /// Number of float parameters (weights and biases).
    pub fn parameter_count(&self) -> usize {
        self.layers.iter().map(|l| l.w.len() + l.b.len()).sum()
    }

    /// Forward pass in plain f32 (the arithmetic of the C export: the same
    /// order of sums, so both agree to rounding).
    pub fn forward_f32(&self, activations: &[Activation], x: &[f32]) -> Vec<f32> {
        let mut h = x.to_vec();
        for (l, act) in self.layers.iter().zip(activations) {
            let mut out = l.b.clone();
            for (i, xi) in h.iter().enumerate() {
                let row = &l.w[i * l.outputs..(i + 1) * l.outputs];
                for (o, w) in out.iter_mut().zip(row) {
                    *o += xi * w;
                }
            }
            for o in &mut out {
                *o = match act {
                    Activation::Relu => o.max(0.0),
                    Activation::Sigmoid => 1.0 / (1.0 + (-*o).exp()),
                    Activation::Identity => *o,
                };
            }
            h = out;
        }
        h
    }
}

/// Dense layers `layers[i]` each followed by `activations[i]`.
#[derive(Module, Debug)]
pub struct Mlp {
    pub layers: Vec<Linear>,
    #[module(skip)]
    pub activations: Vec<Activation>,
}

/// Shape of an [`Mlp`]: layer widths from inputs to outputs and one activation per layer.
#[derive(Debug, Clone, PartialEq)]
pub struct MlpShape {
    pub widths: Vec<usize>,
    pub activations: Vec<Activation>,
}

impl MlpShape {
    /// `inputs → hidden… → outputs` with the given activations (one per layer).
    pub fn new(inputs: usize, hidden: &[usize], outputs: usize, activations: Vec<Activation>) -> Result<MlpShape, ModelError> {
        let mut widths = vec![inputs];
        widths.extend_from_slice(hidden);
        widths.push(outputs);
        if widths.contains(&0) {
            return Err(ModelError::invalid("widths", format!("{widths:?}"), "every layer needs at least one unit"));
        }
        if activations.len() != widths.len() - 1 {
            return Err(ModelError::Shape(format!("{} activations for {} layers", activations.len(), widths.len() - 1)));
        }
        Ok(MlpShape { widths, activations })
    }

    /// Weights drawn PyTorch-style, uniform(±1/√fan_in), layer by layer (weights then
    /// biases) from `rng::seeded(seed, stream)`.
    pub fn seeded_weights(&self, seed: u64, stream: u64) -> NetWeights {
        let mut rng = crate::rng::seeded(seed, stream);
        let w = &self.widths;
        let layers = (0..w.len() - 1)
            .map(|i| {
                let bound = 1.0 / (w[i] as f32).sqrt();
                let mut draw = |n: usize| (0..n).map(|_| rng.random_range(-bound..bound)).collect::<Vec<f32>>();
                let wv = draw(w[i] * w[i + 1]);
                let bv = draw(w[i + 1]);
                DenseWeights { inputs: w[i], outputs: w[i + 1], w: wv, b: bv }
            })
            .collect();
        NetWeights { layers }
    }

    /// A seeded network on `device`.
    pub fn init_seeded(&self, device: &Device, seed: u64, stream: u64) -> Result<Mlp, ModelError> {
        Mlp::from_weights(&self.seeded_weights(seed, stream), &self.activations, device)
    }
}

fn dense(d: &DenseWeights, id: u64, device: &Device) -> Result<Linear, ModelError> {
    if d.w.len() != d.inputs * d.outputs || d.b.len() != d.outputs {
        return Err(ModelError::Shape(format!("dense layer {id}: {}×{} weights, {} biases", d.inputs, d.outputs, d.b.len())));
    }
    let w = Tensor::<2>::from_data(TensorData::new(d.w.clone(), [d.inputs, d.outputs]), device);
    let b = Tensor::<1>::from_data(TensorData::new(d.b.clone(), [d.outputs]), device);
    Ok(Linear {
        weight: Param::initialized(ParamId::from(2 * id), require_grad_if(w, device)),
        bias: Some(Param::initialized(ParamId::from(2 * id + 1), require_grad_if(b, device))),
    })
}

/// Mark parameters trainable only on an autodiff device.
fn require_grad_if<const D: usize>(t: Tensor<D>, device: &Device) -> Tensor<D> {
    if device.is_autodiff() {
        t.require_grad()
    } else {
        t
    }
}

fn numerical(e: impl std::fmt::Debug) -> ModelError {
    ModelError::Numerical(format!("{e:?}"))
}

fn weights_of(l: &Linear) -> Result<DenseWeights, ModelError> {
    let [inputs, outputs] = l.weight.shape().dims();
    let w = l.weight.val().into_data().try_into_vec::<f32>().map_err(numerical)?;
    let b = match &l.bias {
        Some(b) => b.val().into_data().try_into_vec::<f32>().map_err(numerical)?,
        None => vec![0.0; outputs],
    };
    Ok(DenseWeights { inputs, outputs, w, b })
}

/// Renames `layers.<i>.` to the caller's layer names when saving a Burnpack.
#[derive(Clone)]
struct LayerNames(Vec<String>);

impl ModuleAdapter for LayerNames {
    fn adapt(&self, mut tensor: burn::store::burn_pack::Tensor, _ctx: ModuleContext<'_>) -> burn::store::burn_pack::Tensor {
        if let Some(rest) = tensor.name.strip_prefix("layers.") {
            if let Some((i, tail)) = rest.split_once('.') {
                if let Some(name) = i.parse::<usize>().ok().and_then(|i| self.0.get(i)) {
                    tensor.name = format!("{name}.{tail}");
                }
            }
        }
        tensor
    }

    fn clone_box(&self) -> Box<dyn ModuleAdapter> {
        Box::new(self.clone())
    }
}

impl Mlp {
    /// Rebuild a network from plain weights (chained widths, one activation per layer).
    pub fn from_weights(weights: &NetWeights, activations: &[Activation], device: &Device) -> Result<Mlp, ModelError> {
        let l = &weights.layers;
        if l.is_empty() || l.len() != activations.len() || l.windows(2).any(|p| p[0].outputs != p[1].inputs) {
            return Err(ModelError::Shape(format!("expected {} chained dense layers, got {}", activations.len(), l.len())));
        }
        let layers = l.iter().enumerate().map(|(i, d)| dense(d, i as u64, device)).collect::<Result<Vec<_>, _>>()?;
        Ok(Mlp { layers, activations: activations.to_vec() })
    }

    /// Plain weights, for artifacts and exports.
    pub fn weights(&self) -> Result<NetWeights, ModelError> {
        Ok(NetWeights { layers: self.layers.iter().map(weights_of).collect::<Result<_, _>>()? })
    }

    /// Input width.
    pub fn inputs(&self) -> usize {
        self.layers.first().map(|l| l.weight.val().dims()[0]).unwrap_or(0)
    }

    /// Output width.
    pub fn outputs(&self) -> usize {
        self.layers.last().map(|l| l.weight.val().dims()[1]).unwrap_or(0)
    }

    /// The network in burn's Burnpack format (`.bpk`) with tensor paths
    /// `<names[i]>.weight` / `<names[i]>.bias` (`layers.<i>.…` when `names` is empty).
    pub fn to_burnpack(&self, names: &[&str]) -> Result<Vec<u8>, ModelError> {
        let mut store = BurnpackStore::from_bytes(None).with_to_adapter(LayerNames(names.iter().map(|s| s.to_string()).collect()));
        self.save_into(&mut store).map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?;
        Ok(store.get_bytes().map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?.to_vec())
    }

    /// Load a network of the given shape from Burnpack bytes written with the same `names`.
    pub fn from_burnpack(bytes: &[u8], shape: &MlpShape, names: &[&str], device: &Device) -> Result<Mlp, ModelError> {
        let mut net = shape.init_seeded(device, 0, 0)?;
        let mut remap = KeyRemapper::new();
        for (i, n) in names.iter().enumerate() {
            remap =
                remap.add_pattern(format!("^{}\\.", regex_escape(n)), format!("layers.{i}.")).map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?;
        }
        let mut store = BurnpackStore::from_bytes(Some(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))).remap(remap);
        net.load_from(&mut store).map_err(|e| ModelError::Numerical(format!("burnpack: {e}")))?;
        Ok(net)
    }

    /// Forward pass on a batch `[rows, inputs]` → `[rows, outputs]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let mut h = x;
        for (l, act) in self.layers.iter().zip(&self.activations) {
            h = l.forward(h);
            h = match act {
                Activation::Relu => relu(h),
                Activation::Sigmoid => sigmoid(h),
                Activation::Identity => h,
            };
        }
        h
    }

    /// Predict row-major inputs (`inputs` columns) → row-major outputs.
    pub fn predict(&self, x: &[f32], inputs: usize) -> Result<Vec<f32>, ModelError> {
        if inputs == 0 || x.len() % inputs != 0 {
            return Err(ModelError::Shape(format!("{} values are not rows of {inputs}", x.len())));
        }
        let Some(first) = self.layers.first() else { return Err(ModelError::Shape("empty network".into())) };
        let device = first.weight.val().device();
        let t = Tensor::<2>::from_data(TensorData::new(x.to_vec(), [x.len() / inputs, inputs]), &device);
        self.forward(t).into_data().try_into_vec::<f32>().map_err(numerical)
    }
}

/// Escape a layer name for the remapping regex (names are `[a-z0-9_]`, but be safe).
fn regex_escape(s: &str) -> String {
    s.chars().flat_map(|c| if c.is_ascii_alphanumeric() || c == '_' { vec![c] } else { vec!['\\', c] }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape() -> MlpShape {
        MlpShape::new(4, &[8, 6], 2, vec![Activation::Relu, Activation::Sigmoid, Activation::Identity]).expect("shape")
    }

    #[test]
    fn weights_round_trip_and_seed_determinism() {
        let dev = Device::flex();
        let a = shape().init_seeded(&dev, 5, 1).and_then(|n| n.weights()).expect("w");
        assert_eq!(a, shape().init_seeded(&dev, 5, 1).and_then(|n| n.weights()).expect("w"));
        assert_ne!(a, shape().init_seeded(&dev, 6, 1).and_then(|n| n.weights()).expect("w"));
        let back = Mlp::from_weights(&a, &shape().activations, &dev).and_then(|n| n.weights());
        assert_eq!(back.ok(), Some(a));
    }

    #[test]
    fn plain_forward_matches_burn() {
        // Same arithmetic in f32: agreement to a few ulps of the outputs' size.
        let dev = Device::flex();
        let net = shape().init_seeded(&dev, 9, 0).expect("net");
        let w = net.weights().expect("w");
        let x = [0.3f32, -1.2, 0.7, 2.0, 0.0, 0.1, -0.4, 1.5];
        let burn = net.predict(&x, 4).expect("predict");
        for r in 0..2 {
            let plain = w.forward_f32(&shape().activations, &x[r * 4..r * 4 + 4]);
            for o in 0..2 {
                assert!((plain[o] - burn[r * 2 + o]).abs() < 1e-5, "{plain:?} {burn:?}");
            }
        }
    }

    #[test]
    fn burnpack_round_trip_with_named_layers() {
        let dev = Device::flex();
        let net = shape().init_seeded(&dev, 11, 0).expect("net");
        for names in [&["a", "b", "out"][..], &[][..]] {
            let bytes = net.to_burnpack(names).expect("save");
            assert_eq!(bytes, shape().init_seeded(&dev, 11, 0).and_then(|n| n.to_burnpack(names)).expect("save again"));
            let back = Mlp::from_burnpack(&bytes, &shape(), names, &dev).expect("load");
            assert_eq!(back.weights().expect("w"), net.weights().expect("w"));
        }
        // Other widths refuse the file instead of loading garbage.
        let other = MlpShape::new(4, &[8], 2, vec![Activation::Relu, Activation::Identity]).expect("shape");
        assert!(Mlp::from_burnpack(&net.to_burnpack(&[]).expect("save"), &other, &[], &dev).is_err());
    }
}
