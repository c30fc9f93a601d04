//! The K_A regressor of Zimenko, Afanasev, Kolesnikov (2022): dense layers with
//! ReLU on every hidden layer but the last, a sigmoid layer, and one linear
//! output (the source's three layers: ReLU, ReLU, sigmoid), trained with the
//! shared loop ([`super::train::fit`], MSE, Adam) on min–max scaled data.

use super::mlp::{Activation, Mlp, MlpShape};
use super::params::ValidTrainParams;
use super::train::{fit, mse, OnEpoch, Rows};
use crate::ModelError;
use burn::prelude::Device;

/// Random stream of the K_A network's initial weights.
const INIT_STREAM: u64 = 0x6b61;

/// Activations of a K_A network with `hidden` layers: ReLU…, sigmoid, identity.
pub fn activations(hidden: usize) -> Vec<Activation> {
    let mut a = vec![Activation::Relu; hidden.saturating_sub(1)];
    a.extend([Activation::Sigmoid, Activation::Identity]);
    a
}

/// Shape of a K_A network: `inputs → hidden… → 1`.
pub fn shape(inputs: usize, hidden: &[usize]) -> Result<MlpShape, ModelError> {
    MlpShape::new(inputs, hidden, 1, activations(hidden.len()))
}

/// Burnpack tensor names of the layers: `l1`, `l2`, …, `out` (the paths burn
/// programs load, unchanged since the first K_A artifacts).
pub fn layer_names(hidden: usize) -> Vec<String> {
    (1..=hidden).map(|i| format!("l{i}")).chain(["out".to_string()]).collect()
}

/// Train a K_A network on row-major scaled inputs `x` (`inputs` columns) and
/// scaled targets `y`; `on_epoch` hears every epoch.
pub fn train(inputs: usize, params: &ValidTrainParams, x: &[f32], y: &[f32], on_epoch: OnEpoch<'_>) -> Result<Mlp, ModelError> {
    fit(&shape(inputs, params.hidden())?, INIT_STREAM, params, Rows { x, y, inputs, outputs: 1 }, &mse, on_epoch)
}

/// The network in Burnpack bytes (paths `l1.weight`, …, `out.bias`).
pub fn to_burnpack(net: &Mlp) -> Result<Vec<u8>, ModelError> {
    let names = layer_names(net.layers.len().saturating_sub(1));
    net.to_burnpack(&names.iter().map(String::as_str).collect::<Vec<_>>())
}

/// Load a K_A network of `inputs → hidden… → 1` from Burnpack bytes.
pub fn from_burnpack(bytes: &[u8], inputs: usize, hidden: &[usize], device: &Device) -> Result<Mlp, ModelError> {
    let names = layer_names(hidden.len());
    Mlp::from_burnpack(bytes, &shape(inputs, hidden)?, &names.iter().map(String::as_str).collect::<Vec<_>>(), device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn burnpack_paths_are_the_named_layers() {
        let dev = Device::flex();
        let net = shape(4, &[8, 6, 5]).and_then(|s| s.init_seeded(&dev, 11, INIT_STREAM)).expect("net");
        let bytes = to_burnpack(&net).expect("save");
        let text = String::from_utf8_lossy(&bytes);
        for p in ["l1.weight", "l2.bias", "l3.weight", "out.bias"] {
            assert!(text.contains(p), "{p}");
        }
        let back = from_burnpack(&bytes, 4, &[8, 6, 5], &dev).expect("load");
        assert_eq!(back.weights().expect("w"), net.weights().expect("w"));
        assert!(from_burnpack(&bytes, 4, &[32, 32, 16], &dev).is_err());
    }
}
