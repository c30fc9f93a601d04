//! Turn prediction end to end: `turns train|eval|predict`, `export turns`
//! (compiled with `cc` and matched against burn), the `turn-prediction` kind,
//! bad input. Training here is tiny (a few epochs on synthetic prints).

use crate::common::Sandbox;
use std::fmt::Write as _;

/// A synthetic print: `layers` layers, each the same closed polygon (a
/// rectangle with chamfered corners, the chamfer a 45° turn pair) traced as
/// short segments, plus a zig-zag infill whose direction alternates per layer.
/// Returns the G-code and, per XY move in file order, its 1-based line.
fn print(layers: usize, w: f64, h: f64, seg: f64) -> (String, Vec<usize>) {
    let mut g = String::from("; synthetic test print\nG90\nM83\nG28\nG92 E0\n");
    let mut lines = vec![];
    let mut push = |g: &mut String, cmd: String, xy: bool| {
        g.push_str(&cmd);
        g.push('\n');
        if xy {
            lines.push(g.lines().count());
        }
    };
    let c = 3.0;
    let corners = [(c, 0.0), (w - c, 0.0), (w, c), (w, h - c), (w - c, h), (c, h), (0.0, h - c), (0.0, c), (c, 0.0)];
    for l in 0..layers {
        push(&mut g, format!(";LAYER_CHANGE\n;Z:{:.1}", 0.2 * (l + 1) as f64), false);
        push(&mut g, format!("G1 Z{:.1} F600", 0.2 * (l + 1) as f64), false);
        push(&mut g, format!("G0 X{:.3} Y{:.3} F6000", 10.0 + corners[0].0, 10.0 + corners[0].1), true);
        push(&mut g, ";TYPE:Perimeter".into(), false);
        for k in 1..corners.len() {
            let (a, b) = (corners[k - 1], corners[k]);
            let len = (b.0 - a.0).hypot(b.1 - a.1);
            let n = (len / seg).ceil().max(1.0) as usize;
            for s in 1..=n {
                let f = s as f64 / n as f64;
                push(&mut g, format!("G1 X{:.3} Y{:.3} E{:.5} F1800", 10.0 + a.0 + f * (b.0 - a.0), 10.0 + a.1 + f * (b.1 - a.1), len / n as f64 * 0.03), true);
            }
        }
        push(&mut g, ";TYPE:Internal infill".into(), false);
        // Zig-zag infill: along X on even layers, along Y on odd ones.
        let rows = 6;
        for r in 0..rows {
            let t = 12.0 + r as f64 * (h.min(w) - 4.0) / rows as f64;
            let (p, q) = if r % 2 == 0 { (12.0, 8.0 + w) } else { (8.0 + w, 12.0) };
            let (a, b) = if l % 2 == 0 { ((p, t), (q, t)) } else { ((t, p.min(8.0 + h)), (t, q.min(8.0 + h))) };
            push(&mut g, format!("G1 X{:.3} Y{:.3} E0.1 F3000", a.0, a.1), true);
            push(&mut g, format!("G1 X{:.3} Y{:.3} E0.5 F3000", b.0, b.1), true);
        }
    }
    (g, lines)
}

fn write_corpus(sb: &Sandbox) {
    std::fs::create_dir_all(sb.path().join("train")).expect("dir");
    std::fs::create_dir_all(sb.path().join("test")).expect("dir");
    for (i, (w, h, seg)) in [(30.0, 20.0, 1.0), (24.0, 24.0, 0.7), (40.0, 16.0, 1.3)].iter().enumerate() {
        sb.write(&format!("train/p{i}.gcode"), &print(8, *w, *h, *seg).0);
    }
    sb.write("test/held.gcode", &print(6, 28.0, 22.0, 0.9).0);
}

fn method<'a>(v: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    v["files"][0]["scores"][0]["methods"].as_array().and_then(|m| m.iter().find(|x| x["method"] == name)).unwrap_or(&serde_json::Value::Null)
}

#[test]
fn train_eval_predict_and_determinism() {
    let sb = Sandbox::new();
    write_corpus(&sb);
    let train = ["turns", "train", "--gcode", "train", "--epochs", "3", "--hidden", "16,16"];
    let v = sb.json(&train);
    let run = v["run"].as_str().expect("run id").to_string();
    assert!(v["junctions"].as_u64().unwrap_or(0) > 1000, "{v}");
    assert!(v["weight_bytes"].as_u64().unwrap_or(u64::MAX) < 16 * 1024);
    // A call threshold per default buffer (16, 4, 2) and horizon, for the network
    // and, tuned alike, for each of the five baselines; the previous-layer match
    // chosen from the documented grid (6 radii × 4 tolerances).
    assert_eq!(v["call_thresholds"].as_array().map(Vec::len), Some(9), "{v}");
    assert_eq!(v["baselines"]["call_thresholds"].as_array().map(Vec::len), Some(5 * 9), "{v}");
    assert_eq!(v["baselines"]["previous_layer_trials"].as_array().map(Vec::len), Some(24), "{v}");
    // Same data, same seed: the same model, byte for byte.
    assert_eq!(sb.json(&train)["model"], v["model"]);

    let e = sb.json(&["turns", "eval", "test/held.gcode", "--model", &run, "--horizon", "16"]);
    let names: Vec<&str> = e["files"][0]["scores"][0]["methods"].as_array().expect("methods").iter().filter_map(|m| m["method"].as_str()).collect();
    assert_eq!(names[0], "network");
    assert!(names.len() >= 4, "every baseline is listed: {names:?}");
    // "No turn" predicts 0°, so its MAE is the mean turn of the targets: the
    // network, which sees the layers below, must do better than that.
    let net = method(&e, "network");
    let none = method(&e, "no-turn");
    assert!(net["mae_deg"].as_f64().unwrap_or(f64::NAN) < none["mae_deg"].as_f64().unwrap_or(0.0), "{e}");
    // The line-width comparison: every method at each default buffer; a method that
    // never calls a corner ("no turn") leaves the buffer alone's width exactly.
    let down = e["files"][0]["downstream"].as_array().expect("downstream");
    assert_eq!(down.len(), 3 * names.len(), "{e}");
    for d in down.iter().filter(|d| d["method"] == "no-turn") {
        assert_eq!(d["false_calls"], 0);
        assert_eq!(d["width_error"], d["width_error_buffer_alone"], "{d}");
    }

    // Predictions: one row per junction i + H, the line of the move ending there.
    let (text, lines) = print(6, 28.0, 22.0, 0.9);
    sb.write("held.gcode", &text);
    let p = sb.json(&["turns", "predict", "held.gcode", "--model", "latest", "--horizon", "32", "--out", "pred.csv"]);
    let csv = std::fs::read_to_string(sb.path().join("pred.csv")).expect("csv");
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[0], "line,predicted_deg,corner_probability");
    // n moves → n − 1 junctions → n − 1 − H predictions; junction j ends move j.
    assert_eq!(rows.len() - 1, lines.len() - 1 - 32);
    assert_eq!(p["rows"].as_u64(), Some((lines.len() - 1 - 32) as u64));
    for (k, row) in rows[1..].iter().enumerate() {
        let f: Vec<&str> = row.split(',').collect();
        assert_eq!(f[0].parse::<usize>().ok(), Some(lines[k + 32]), "row {k}");
        let deg: f64 = f[1].parse().expect("deg");
        let prob: f64 = f[2].parse().expect("prob");
        assert!((0.0..=180.0).contains(&deg) && (0.0..=1.0).contains(&prob));
    }
}

#[test]
fn eval_takes_a_folder_of_plain_and_gzipped_files_and_pools_them() {
    let sb = Sandbox::new();
    write_corpus(&sb);
    let run = sb.json(&["turns", "train", "--gcode", "train/p0.gcode", "--epochs", "1", "--hidden", "8"])["run"].as_str().expect("run").to_string();
    std::fs::create_dir_all(sb.path().join("prints")).expect("dir");
    sb.write("prints/a.gcode", &print(5, 26.0, 18.0, 1.1).0);
    // A gzipped arc program of the shipped corpus (G2/G3, G91 chains).
    std::fs::copy(fdmlab_datasets::turns::shipped_corpus().join("arcs-3--synthetic.gcode.gz"), sb.path().join("prints/b.gcode.gz")).expect("copy");
    let e = sb.json(&["turns", "eval", "prints", "--model", &run, "--horizon", "16,32", "--blocks", "4,2"]);
    let files = e["files"].as_array().expect("files");
    assert_eq!(files.len(), 2, "{e}");
    let agg = &e["aggregate"];
    // The aggregate's junctions are the files' together; its gains have their
    // point inside the bootstrap interval, one per buffer, horizon and method.
    let sum: u64 = files.iter().filter_map(|f| f["junctions"].as_u64()).sum();
    assert_eq!(agg["junctions"].as_u64(), Some(sum));
    let gains = agg["gains"].as_array().expect("gains");
    assert_eq!(gains.len(), agg["downstream"].as_array().map_or(0, Vec::len));
    assert_eq!(gains.len(), 2 * 2 * 6, "{e}");
    for g in gains {
        let (lo, x, hi) = (g["lo_pp"].as_f64().unwrap_or(f64::NAN), g["gain_pp"].as_f64().unwrap_or(f64::NAN), g["hi_pp"].as_f64().unwrap_or(f64::NAN));
        assert!(lo <= x + 1e-9 && x <= hi + 1e-9, "{g}");
        assert_eq!(g["per_file_pp"].as_array().map(Vec::len), Some(2));
    }
    // The text form: one table per file, then the aggregate.
    let text = sb.ok(&["turns", "eval", "prints", "--model", &run]);
    assert!(text.contains("a.gcode:") && text.contains("b.gcode.gz:") && text.contains("aggregate: 2 file(s)"), "{text}");
}

#[test]
fn train_help_states_the_turn_networks_defaults() {
    // Issue #25 item 7: not K_A's 64,64,32 and 500 epochs, and the 10 mm corner window.
    let sb = Sandbox::new();
    let help = sb.ok(&["turns", "train", "--help"]);
    let d = fdmlab_models::turns::net::default_params(7);
    assert!(!help.contains("K_A"), "{help}");
    assert!(help.contains("(default 32,32)") && help.contains(&format!("(default {})", d.train.epochs)) && help.contains("(default 256)"), "{help}");
    assert!(help.contains("[default: 10]"), "{help}");
}

#[test]
fn c_header_compiles_and_matches_burn() {
    let sb = Sandbox::new();
    write_corpus(&sb);
    let v = sb.json(&["turns", "train", "--gcode", "train", "--epochs", "1", "--hidden", "24,16"]);
    let run = v["run"].as_str().expect("run");
    let header = sb.ok(&["export", "turns", "--model", run, "--format", "c-header"]);
    assert!(!header.contains("malloc"));
    std::fs::write(sb.path().join("fdmlab_turns.h"), &header).expect("write");
    // The model and features from the library, the outputs from C.
    let rec = sb.json(&["runs", "show", run]);
    let hash =
        rec["stages"][0]["outputs"].as_array().and_then(|o| o.iter().find(|x| x["name"] == "turn-model.json")).and_then(|o| o["hash"].as_str()).expect("model");
    let model = fdmlab_datasets::turns::stored::model_from_json(&sb.run(&["cat", hash]).stdout, "model").expect("model");
    let moves = fdmlab_datasets::turns::read_moves(&sb.path().join("test/held.gcode")).expect("moves");
    let j = fdmlab_models::turns::junctions(&moves);
    let x = fdmlab_models::turns::features::features(&j, &model.task);
    let cols = model.task.inputs();
    let anchors: Vec<usize> = (0..j.len() - 64).step_by(37).collect();
    let mut main = String::from("#include <stdio.h>\n#include \"fdmlab_turns.h\"\nint main(void) {\n");
    let _ = writeln!(main, "  static const float x[{}][FDMLAB_TURNS_INPUTS] = {{", anchors.len());
    for &i in &anchors {
        let _ = writeln!(main, "    {{{}}},", x[i * cols..(i + 1) * cols].iter().map(|v| format!("{v:e}f")).collect::<Vec<_>>().join(","));
    }
    let _ = writeln!(main, "  }};\n  float a[FDMLAB_TURNS_HORIZONS], c[FDMLAB_TURNS_HORIZONS];");
    let _ = writeln!(main, "  for (int r = 0; r < {}; ++r) {{ fdmlab_turns_predict(x[r], a, c); for (int k = 0; k < FDMLAB_TURNS_HORIZONS; ++k) printf(\"%.9g %.9g\\n\", a[k], c[k]); }}\n  return 0;\n}}", anchors.len());
    std::fs::write(sb.path().join("main.c"), main).expect("main");
    let out = std::process::Command::new("cc")
        .current_dir(sb.path())
        .args(["-std=c99", "-O2", "-Wall", "-Werror", "-o", "turns", "main.c", "-lm"])
        .output()
        .expect("cc runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let run_c = std::process::Command::new(sb.path().join("turns")).output().expect("runs");
    let c: Vec<(f64, f64)> = String::from_utf8_lossy(&run_c.stdout)
        .lines()
        .map(|l| {
            let mut it = l.split(' ').map(|v| v.parse::<f64>().unwrap_or(f64::NAN));
            (it.next().unwrap_or(f64::NAN), it.next().unwrap_or(f64::NAN))
        })
        .collect();
    let hs = model.task.horizons.clone();
    assert_eq!(c.len(), anchors.len() * hs.len());
    for (k, &h) in hs.iter().enumerate() {
        let burn = model.predict(&j, h).expect("burn");
        for (r, &i) in anchors.iter().enumerate() {
            let (ca, cp) = c[r * hs.len() + k];
            // Both are f32 forward passes of the same weights in a different summation
            // order: the bound, 1e-5, on the network's outputs (angle / 180, probability).
            assert!((ca / 180.0 - burn.angle_deg[i] / 180.0).abs() < 1e-5, "H {h} anchor {i}: C {ca} burn {}", burn.angle_deg[i]);
            assert!((cp - burn.corner_probability[i]).abs() < 1e-5, "H {h} anchor {i}: C {cp} burn {}", burn.corner_probability[i]);
        }
    }
    let js: serde_json::Value = serde_json::from_str(&sb.ok(&["export", "turns", "--model", run, "--format", "json"])).expect("json export");
    assert_eq!(js["schema"], "fdmlab.turns-export/1");
    assert!(js["weight_bytes"].as_u64().unwrap_or(u64::MAX) < 16 * 1024);
}

#[test]
fn spec_kind_runs_and_latest_finds_its_model() {
    let sb = Sandbox::new();
    write_corpus(&sb);
    sb.write(
        "turns.toml",
        "[experiment]\nname = \"turns-tiny\"\nkind = \"turn-prediction\"\nseed = 3\n\n[data]\ntrain = [\"train\"]\ntest = [\"test/held.gcode\"]\n\n[model]\nhidden = [8, 8]\nepochs = 1\n",
    );
    let runs = sb.json(&["run", "turns.toml"]);
    let rec = &runs[0];
    let names: Vec<&str> = rec["stages"].as_array().expect("stages").iter().filter_map(|s| s["name"].as_str()).collect();
    assert_eq!(names, ["train", "eval", "export", "report"]);
    let report = std::fs::read_to_string(sb.store().join("reports/turns-tiny/report.md")).expect("report");
    assert!(report.contains("previous-layer") && report.contains("too late"), "{report}");
    // The line-width comparison at every default buffer (16, 4 and 2 blocks).
    let eval = &rec["stages"][1]["metrics"];
    for key in ["width_error_planner_h16", "width_error_predicted_h16_b4", "late_planner_h64_b2"] {
        assert!(eval[key].is_number(), "{key}: {eval}");
    }
    // `--model latest` is that run's model.
    let e = sb.json(&["turns", "eval", "test/held.gcode", "--horizon", "64"]);
    let train_out = rec["stages"][0]["outputs"].as_array().and_then(|o| o.iter().find(|x| x["name"] == "turn-model.json")).expect("model");
    assert_eq!(e["model"], train_out["hash"]);
    // A bad value is pointed at in the spec and runs nothing.
    sb.write(
        "bad.toml",
        "[experiment]\nname = \"b\"\nkind = \"turn-prediction\"\nseed = 3\n\n[data]\ntrain = [\"train\"]\ntest = [\"test\"]\n\n[model]\nepochs = 0\n",
    );
    let out = sb.run(&["run", "bad.toml"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml:11") && err.contains("model.epochs"), "{err}");
}

#[test]
fn bad_input_is_named_and_exits_2() {
    let sb = Sandbox::new();
    write_corpus(&sb);
    // No model in the store yet.
    assert_eq!(sb.run(&["turns", "eval", "test/held.gcode"]).status.code(), Some(2));
    sb.json(&["turns", "train", "--gcode", "train/p0.gcode", "--epochs", "1", "--hidden", "8"]);
    // A horizon the model was not trained for, a missing file, a malformed line.
    let out = sb.run(&["turns", "eval", "test/held.gcode", "--horizon", "7"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(sb.run(&["turns", "predict", "nope.gcode", "--out", "p.csv"]).status.code(), Some(2));
    sb.write("bad.gcode", "G90\nG1 X1 Y1 F600\nG1 X2 Yabc\n");
    let out = sb.run(&["turns", "predict", "bad.gcode", "--out", "p.csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("bad.gcode:3"), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!sb.path().join("p.csv").exists(), "no partial output");
    // Training limits come from the one parameter table.
    let out = sb.run(&["turns", "train", "--gcode", "train", "--epochs", "100001"]);
    assert_eq!(out.status.code(), Some(2));
    let out = sb.run(&["turns", "train", "--gcode", "train", "--horizons", "0,16"]);
    assert_eq!(out.status.code(), Some(2));
    let out = sb.run(&["turns", "train", "--gcode", "train", "--blocks", "4,4"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--blocks"), "{}", String::from_utf8_lossy(&out.stderr));
}

/// The bundled `turn-prediction` run (trained on some model families, its and
/// every baseline's thresholds tuned on another, scored on two families it never
/// saw, every slicer in each): the network beats every tuned non-trivial
/// baseline on angle MAE and corner F1 at every horizon, and its calls raise
/// the line-width error of no held-out file at any buffer (docs/turns.md: on
/// this spec's 8 tuning files no rule's leave-one-file-out gain reaches the
/// effect floor, so it abstains and the pooled gain is 0).
pub fn network_beats_every_baseline(runs: &serde_json::Value) {
    let run = runs.as_array().and_then(|r| r.iter().find(|r| r["spec_path"].as_str().is_some_and(|p| p.ends_with("turn-prediction.toml")))).expect("turn run");
    let m = &run["stages"][1]["metrics"];
    let get = |k: &str| m[k].as_f64().unwrap_or_else(|| panic!("metric {k}: {m}"));
    for h in [16, 32, 64] {
        for b in ["last-turn", "previous-layer", "knn"] {
            assert!(get(&format!("network_mae_h{h}")) < get(&format!("{b}_mae_h{h}")), "MAE at H {h} vs {b}");
            assert!(get(&format!("network_f1_h{h}")) > get(&format!("{b}_f1_h{h}")), "F1 at H {h} vs {b}");
        }
        // Do no harm (docs/turns.md): no held-out file above the buffer alone at
        // any buffer and H, and the pooled width never raised.
        for buf in ["", "_b4", "_b2"] {
            assert!(get(&format!("network_gain_pp_h{h}{buf}")) <= 1e-9, "pooled width at H {h}{buf}");
            assert_eq!(get(&format!("network_files_worse_h{h}{buf}")), 0.0, "files made worse at H {h}{buf}");
        }
    }
}
