//! C99 emission of a dense network, shared by the K_A and turn-network headers:
//! weight arrays, one function per layer (`y = act(x W + b)`, sizes as constants so
//! compilers vectorise the inner loop) and the ping-pong chain through two buffers.

use fdmlab_models::nets::{Activation, DenseWeights};
use std::fmt::Write as _;

/// Floats as a C initialiser list (`1e0f, 2.5e-1f`).
pub fn c_floats(v: impl Iterator<Item = f32>) -> String {
    v.map(|x| format!("{x:e}f")).collect::<Vec<_>>().join(", ")
}

/// `static const float {prefix}_w{i}[…]` and `{prefix}_b{i}[…]` for every layer.
pub fn weights(s: &mut String, prefix: &str, layers: &[DenseWeights]) {
    for (i, l) in layers.iter().enumerate() {
        let _ = writeln!(s, "static const float {prefix}_w{i}[{}] = {{{}}};", l.w.len(), c_floats(l.w.iter().copied()));
        let _ = writeln!(s, "static const float {prefix}_b{i}[{}] = {{{}}};", l.b.len(), c_floats(l.b.iter().copied()));
    }
}

/// `static void {prefix}_layer{i}(x, y)` for every layer; `acts[i]` (none past the end:
/// identity) is applied in place.
pub fn layer_functions(s: &mut String, prefix: &str, layers: &[DenseWeights], acts: &[Activation]) {
    let _ = writeln!(s, "\n/* Layer k: y = act(x W + b), W row-major [inputs][outputs]. */");
    for (i, l) in layers.iter().enumerate() {
        let _ = writeln!(
            s,
            "static void {prefix}_layer{i}(const float *restrict x, float *restrict y) {{\n  for (int o = 0; o < {no}; ++o) y[o] = {prefix}_b{i}[o];\n  for (int i = 0; i < {ni}; ++i) {{\n    const float xi = x[i];\n    const float *wr = {prefix}_w{i} + i * {no};\n    for (int o = 0; o < {no}; ++o) y[o] += xi * wr[o];\n  }}",
            no = l.outputs,
            ni = l.inputs
        );
        let act = match acts.get(i) {
            Some(Activation::Relu) => Some("y[o] = y[o] > 0.0f ? y[o] : 0.0f;"),
            Some(Activation::Sigmoid) => Some("y[o] = 1.0f / (1.0f + expf(-y[o]));"),
            _ => None,
        };
        if let Some(act) = act {
            let _ = writeln!(s, "  for (int o = 0; o < {}; ++o) {act}", l.outputs);
        }
        let _ = writeln!(s, "}}\n");
    }
}

/// Calls of the `n` layer functions from buffer `a` through `b` and back; returns the
/// buffer holding the output.
pub fn layer_chain(s: &mut String, prefix: &str, n: usize) -> &'static str {
    let mut from_a = true;
    for i in 0..n {
        let (src, dst) = if from_a { ("a", "b") } else { ("b", "a") };
        let _ = writeln!(s, "  {prefix}_layer{i}({src}, {dst});");
        from_a = !from_a;
    }
    if from_a {
        "a"
    } else {
        "b"
    }
}

/// The widest layer side: the size of each ping-pong buffer.
pub fn widest(layers: &[DenseWeights]) -> usize {
    layers.iter().map(|l| l.outputs.max(l.inputs)).max().unwrap_or(1)
}
