//! The one training loop of fdmlab's networks: Adam (Kingma & Ba 2015) on
//! seeded shuffled mini-batches with a half-cosine learning-rate decay, any
//! loss, and a progress callback after every epoch (the CLI draws a bar from it;
//! the numbers never depend on whether anyone listens).

use super::mlp::{Mlp, MlpShape};
use super::params::ValidTrainParams;
use crate::ModelError;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use rand::seq::SliceRandom;

/// What the trainer reports after each epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Cross-validation fold being trained (1-based) and the number of fits in
    /// all (folds + the final fit); both 1 outside cross-validation.
    pub fold: usize,
    pub folds: usize,
    /// Epochs done (1-based).
    pub epoch: usize,
    pub epochs: usize,
    /// Mean training loss over the epoch's batches.
    pub loss: f64,
}

/// A listener for [`Progress`]; `&mut |_| {}` for none.
pub type OnEpoch<'a> = &'a mut dyn FnMut(Progress);

/// Rows to train on: row-major inputs `x` (`inputs` columns) and targets `y` (`outputs` columns).
#[derive(Debug, Clone, Copy)]
pub struct Rows<'a> {
    pub x: &'a [f32],
    pub y: &'a [f32],
    pub inputs: usize,
    pub outputs: usize,
}

impl Rows<'_> {
    fn len(&self) -> Result<usize, ModelError> {
        let (d, o) = (self.inputs, self.outputs);
        if d == 0 || o == 0 || self.x.len() % d != 0 || self.y.len() != self.x.len() / d * o || self.y.is_empty() {
            return Err(ModelError::Shape(format!("{} inputs and {} targets are not rows of {d} → {o}", self.x.len(), self.y.len())));
        }
        Ok(self.y.len() / o)
    }
}

/// Relabel the progress of one fit as fit `fold` of `folds`.
pub fn in_fold<'a>(fold: usize, folds: usize, on_epoch: &'a mut dyn FnMut(Progress)) -> impl FnMut(Progress) + 'a {
    move |p| on_epoch(Progress { fold, folds, ..p })
}

/// Mean squared error over every output (the K_A regressor's loss).
pub fn mse(pred: Tensor<2>, y: Tensor<2>) -> Tensor<1> {
    (pred - y).square().mean()
}

/// Train a network of `shape` (weights from `rng::seeded(seed, init_stream)`) on
/// `rows` minimising `loss(prediction, target)`; returns the inference copy
/// (`valid()`, no autodiff) on the flex device. Same seed, same rows → the same
/// network bit for bit.
pub fn fit(
    shape: &MlpShape,
    init_stream: u64,
    params: &ValidTrainParams,
    rows: Rows<'_>,
    loss: &dyn Fn(Tensor<2>, Tensor<2>) -> Tensor<1>,
    on_epoch: OnEpoch<'_>,
) -> Result<Mlp, ModelError> {
    let n = rows.len()?;
    let (d, o) = (rows.inputs, rows.outputs);
    if shape.widths.first() != Some(&d) || shape.widths.last() != Some(&o) {
        return Err(ModelError::Shape(format!("network {:?} does not take {d} inputs to {o} outputs", shape.widths)));
    }
    let device = Device::flex().autodiff();
    let mut model = shape.init_seeded(&device, params.seed(), init_stream)?;
    let mut optim = AdamConfig::new().init();
    let mut rng = crate::rng::seeded(params.seed(), 0x7472);
    let mut order: Vec<usize> = (0..n).collect();
    let bs = params.batch_size().min(n);
    let (mut xb, mut yb) = (Vec::with_capacity(bs * d), Vec::with_capacity(bs * o));
    let epochs = params.epochs();
    for epoch in 0..epochs {
        let lr = params.learning_rate_at(epoch);
        order.shuffle(&mut rng);
        let mut losses = Vec::with_capacity(n.div_ceil(bs));
        for batch in order.chunks(bs) {
            xb.clear();
            yb.clear();
            for &i in batch {
                xb.extend_from_slice(&rows.x[i * d..(i + 1) * d]);
                yb.extend_from_slice(&rows.y[i * o..(i + 1) * o]);
            }
            let xt = Tensor::<2>::from_data(TensorData::new(xb.clone(), [batch.len(), d]), &device);
            let yt = Tensor::<2>::from_data(TensorData::new(yb.clone(), [batch.len(), o]), &device);
            let l = loss(model.forward(xt), yt);
            losses.push(l.clone().detach());
            let grads = GradientsParams::from_grads(l.backward(), &model);
            model = optim.step(lr, model, grads);
        }
        // One read-back per epoch, not per batch.
        let mean = Tensor::cat(losses, 0).mean().into_scalar::<f32>() as f64;
        on_epoch(Progress { fold: 1, folds: 1, epoch: epoch + 1, epochs, loss: mean });
    }
    Ok(model.valid())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nets::mlp::Activation;
    use crate::nets::params::TrainParams;
    use rand::Rng as _;

    #[test]
    fn learns_a_smooth_function_deterministically_and_reports_every_epoch() {
        // y = 0.2 + 0.5·x0·x1 on [0,1]²: 400 points, 300 epochs. A 32-32-16 net fits this
        // to well under 0.02 RMS; the bound is loose to stay robust to float ordering.
        let mut rng = crate::rng::seeded(3, 0);
        let (mut x, mut y) = (vec![], vec![]);
        for _ in 0..400 {
            let (a, b): (f32, f32) = (rng.random(), rng.random());
            x.extend([a, b]);
            y.push(0.2 + 0.5 * a * b);
        }
        let mut p = TrainParams::with_hidden(&[32, 32, 16]);
        p.train = crate::nets::params::Schedule { epochs: 300, batch_size: 64, learning_rate: 0.01, seed: 1 };
        let p = p.check().expect("valid");
        let shape = MlpShape::new(2, p.hidden(), 1, vec![Activation::Relu, Activation::Relu, Activation::Sigmoid, Activation::Identity]).expect("shape");
        let rows = Rows { x: &x, y: &y, inputs: 2, outputs: 1 };
        let mut seen = vec![];
        let net = fit(&shape, 0x6b61, &p, rows, &mse, &mut |pr| seen.push(pr)).expect("fit");
        assert_eq!(seen.len(), 300);
        assert!(seen.iter().enumerate().all(|(i, s)| s.epoch == i + 1 && s.epochs == 300 && s.loss.is_finite()));
        assert!(seen[299].loss < seen[0].loss);
        let pred = net.predict(&x, 2).expect("predict");
        let rms = (pred.iter().zip(&y).map(|(a, b)| (a - b).powi(2)).sum::<f32>() / 400.0).sqrt();
        assert!(rms < 0.02, "rms {rms}");
        let again = fit(&shape, 0x6b61, &p, rows, &mse, &mut |_| {}).and_then(|n| n.predict(&x, 2)).expect("again");
        assert_eq!(pred, again);
    }
}
