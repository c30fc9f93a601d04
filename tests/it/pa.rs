//! Pressure advance end to end: calibration G-code, refusals, scores, training,
//! prediction, exports and the spec kind.

use crate::common::{copy_spec, stderr, Sandbox};

#[test]
fn gcode_pa_writes_gcode_and_manifest_and_refuses_bad_input() {
    let sb = Sandbox::new();
    let v = sb.json(&["gcode", "pa", "--firmware", "klipper", "-o", "pa.gcode"]);
    assert_eq!(v["regions"], 21);
    let text = std::fs::read_to_string(sb.path().join("pa.gcode")).expect("gcode written");
    assert!(text.contains("SET_PRESSURE_ADVANCE ADVANCE=0.55"));
    assert!(sb.path().join("pa.gcode.json").is_file());
    // Refusals: exit 2, a message, and no file.
    for (args, why) in [
        (vec!["--bed-mm", "100x100"], "bed"),
        (vec!["--bed-mm", "100,100"], "XxY"),
        (vec!["--hotend", "300"], "hotend"),
        (vec!["--firmware", "marlin", "--k-end", "12", "--k-step", "1"], "range"),
        (vec!["--title", "x\nG1 Z-10"], "inject"),
        (vec!["--layer", "1e-9"], "layer"),
        (vec!["--filament", "1e-9"], "filament"),
        (vec!["--k-step", "1e-300"], "K values"),
        (vec!["--firmware", "klipper", "--k-start", "0", "--k-end", "0.00003", "--k-step", "0.00001"], "decimals"),
    ] {
        let mut a = vec!["gcode", "pa", "-o", "bad.gcode"];
        a.extend(args.iter().copied());
        let out = sb.run(&a);
        assert_eq!(out.status.code(), Some(2), "{a:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(why), "{a:?}: {}", stderr(&out));
        assert!(!sb.path().join("bad.gcode").exists() && !sb.path().join("bad.gcode.json").exists());
    }
    // The G-code and its manifest land together or not at all.
    std::fs::create_dir(sb.path().join("both.gcode.json")).expect("a folder in the manifest's place");
    let out = sb.run(&["gcode", "pa", "-o", "both.gcode"]);
    assert!(!out.status.success());
    assert!(!sb.path().join("both.gcode").exists(), "{}", stderr(&out));
}

#[test]
fn gcode_pa_matrix_writes_plates_and_a_manifest_with_flows() {
    let sb = Sandbox::new();
    let base = ["gcode", "pa", "--firmware", "reprap", "--k-end", "0.1", "--k-step", "0.02", "--slow-len", "10"];
    let mut args = base.to_vec();
    args.extend(["--speeds", "50,100,150,200", "--accels", "1000,2000,4000", "-o", "m.gcode"]);
    let v = sb.json(&args);
    let plates: Vec<&str> = v["plates"].as_array().expect("plates").iter().filter_map(|p| p.as_str()).collect();
    // 220 mm bed: 5 patterns per plate (one column) → 3 plates, named m.p1.gcode …
    assert_eq!(plates.len(), 3, "{v}");
    let manifest: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("m.gcode.json")).expect("manifest")).expect("json");
    let patterns = manifest["patterns"].as_array().expect("patterns");
    assert_eq!(patterns.len(), 12);
    for p in patterns {
        let (v, a) = (p["speed_mm_s"].as_f64().expect("speed"), p["accel_mm_s2"].as_f64().expect("accel"));
        // Flow = w·h·v: 0.48 mm × 0.2 mm × v.
        assert!((p["flow_mm3_s"].as_f64().expect("flow") - 0.096 * v).abs() < 1e-9);
        let plate = std::fs::read_to_string(sb.path().join(format!("m.p{}.gcode", p["plate"]))).expect("plate");
        assert!(plate.contains(&format!("\nM204 P{a} T{a}\n")), "pattern {}", p["index"]);
        assert!(plate.contains(&format!("; pattern {}: speed {v} mm/s, accel {a} mm/s^2", p["index"])));
    }
    // Refusals: exit 2, nothing written.
    for (extra, why) in [
        (vec!["--speeds", "10,50", "--accels", "1000"], "slow speed"),
        (vec!["--speeds", "50,abc", "--accels", "1000"], "abc"),
        (vec!["--speeds", "50"], "--accels"),
        (vec!["--speeds", "50,50", "--accels", "1000"], "twice"),
        (vec!["--speeds", "200", "--accels", "1000", "--bed-mm", "100x100"], "bed"),
        (vec!["--speeds", "50", "--accels", "1000", "--hotend", "300"], "hotend"),
    ] {
        let mut a = base.to_vec();
        a.extend(extra.iter().copied());
        a.extend(["-o", "bad.gcode"]);
        let out = sb.run(&a);
        assert_eq!(out.status.code(), Some(2), "{a:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(why), "{a:?}: {}", stderr(&out));
        assert!(!sb.files().iter().any(|f| f.contains("bad.")), "{a:?}");
    }
    // The spec equivalent is checked at its key.
    let spec = sb.write(
        "m.toml",
        "[experiment]\nname = \"m\"\nkind = \"pressure-advance\"\nseed = 1\n[printer]\nfirmware = \"klipper\"\n[calibration]\nk = { start = 0, end = 0.1, step = 0.02 }\nmaterial = \"PLA\"\nhotend_c = 215\nbed_c = 60\nlayer_mm = 0.2\nmatrix = { speeds = [10, 50], accels = [1000] }\n",
    );
    let out = sb.run(&["validate", spec.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("calibration") && stderr(&out).contains("slow speed"), "{}", stderr(&out));
    // A valid matrix spec runs: its gcode stage stores every plate and the matrix manifest
    // (a tiny K table and network keep the rest of the chain short).
    let text = std::fs::read_to_string(&spec)
        .expect("spec")
        .replace("[10, 50]", "[50, 100]")
        .replace("firmware = \"klipper\"", "firmware = \"klipper\"\nbed_mm = [300, 300]");
    let mut csv = String::from("hotend_c,k\n");
    for t in 0..8 {
        csv += &format!("{},{}\n", 200 + 5 * t, 0.6 - 0.005 * t as f64);
    }
    sb.write("t.csv", &csv);
    let tail = "line = { slow_mm_s = 20, fast_mm_s = 80, accel_mm_s2 = 1000, slow_len_mm = 10, fast_len_mm = 40 }\n[dataset]\nsource = \"file\"\nfile = \"t.csv\"\ntarget = \"k\"\n[model]\nhidden = [4, 4, 2]\nepochs = 5\nbatch = 8\nlearning_rate = 0.01\nfolds = 2\n[export]\nformats = [\"json\"]\n";
    let good = sb.write("good.toml", &(text + tail));
    let out = sb.run(&["run", good.to_str().expect("utf8")]);
    assert!(out.status.success(), "{}", stderr(&out));
    let run = sb.json(&["runs", "show", "latest"]);
    let gcode = run["stages"].as_array().expect("stages").iter().find(|s| s["name"] == "gcode").expect("gcode stage");
    let names: Vec<&str> = gcode["outputs"].as_array().expect("outputs").iter().filter_map(|o| o["name"].as_str()).collect();
    assert_eq!(names, ["calibration.p1.gcode", "calibration.json"], "{gcode}");
    assert_eq!(gcode["metrics"]["patterns"], 2.0);
}

#[test]
fn scores_round_trip_through_the_cli() {
    let sb = Sandbox::new();
    sb.ok(&["gcode", "pa", "-o", "pa.gcode", "--k-end", "1.2"]);
    sb.ok(&["ka", "simulate-scores", "--manifest", "pa.gcode.json", "--k-true", "0.625", "-o", "scores.csv"]);
    let v = sb.json(&["ka", "scores", "--manifest", "pa.gcode.json", "--scores", "scores.csv"]);
    // K half-way between the 0.60 and 0.65 lines: the best line is 0.025 off, so only an
    // estimator that interpolates meets a quarter step (0.0125).
    let k = v["best_k"].as_f64().expect("best_k");
    assert!((k - 0.625).abs() < 0.0125, "{v}");
    // Lines far from the optimum score 0 for every rater; those ties cap W well below 1.
    assert!(v["kendall_w"].as_f64().expect("W") > 0.6);
    // A bad row: exit 2 naming row and column.
    sb.write("bad.csv", "line,score,rater\n1,5,a\n2,eleven,a\n");
    let out = sb.run(&["ka", "scores", "--manifest", "pa.gcode.json", "--scores", "bad.csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("bad.csv:3: score"), "{}", stderr(&out));
}

#[test]
fn train_predict_export_on_a_small_table() {
    // A small CSV with a categorical column; few epochs keep the debug test short.
    let sb = Sandbox::new();
    let mut csv = String::from("material,hotend_c,layer_mm,k\n");
    for (m, base) in [("PLA", 0.6), ("PETG", 0.9), ("ABS", 0.5)] {
        for t in 0..7 {
            for h in [0.1, 0.2, 0.3] {
                let temp = 210.0 + 5.0 * t as f64;
                csv += &format!("{m},{temp},{h},{}\n", base * (1.0 - 0.01 * (temp - 210.0)) * (1.0 + 0.3 / (h * 10.0)));
            }
        }
    }
    sb.write("t.csv", &csv);
    let v = sb.json(&["ka", "train", "--data", "t.csv", "--target", "k", "--epochs", "40", "--folds", "3"]);
    assert_eq!(v["folds"], 3);
    assert_eq!(v["rows"], 63);
    let names: Vec<&str> = v["models"].as_array().expect("models").iter().filter_map(|m| m["name"].as_str()).collect();
    assert_eq!(names, ["mlp", "median", "linear", "knn"]);
    let run = v["run"].as_str().expect("run id").to_string();
    let p = sb.json(&["ka", "predict", "--model", &run, "--set", "material=PLA,hotend_c=215,layer_mm=0.2"]);
    // The generating law gives 0.6 · (1 − 0.05) · (1 + 0.3 / 2) = 0.6555 at this row. It is a
    // training row, so the fit error there stays within the MLP's out-of-fold mean error on
    // this table (≈ 0.027 at 40 epochs); 0.03 allows that, and a constant or per-material
    // guess (0.6) misses by 0.055.
    let k = p["k"].as_f64().expect("k");
    assert!((k - 0.6555).abs() < 0.03, "k = {k}, generating law 0.6555");
    // Unknown level and missing feature are bad input.
    let out = sb.run(&["ka", "predict", "--model", &run, "--set", "material=TPU,hotend_c=215,layer_mm=0.2"]);
    assert_eq!(out.status.code(), Some(2));
    let out = sb.run(&["ka", "predict", "--model", &run, "--set", "material=PLA"]);
    assert_eq!(out.status.code(), Some(2));
    // Outside the trained ranges (210–240 °C here) or not a number: refused, not a guess.
    for set in ["material=PLA,hotend_c=1000,layer_mm=0.2", "material=PLA,hotend_c=nan,layer_mm=0.2"] {
        let out = sb.run(&["ka", "predict", "--model", &run, "--set", set]);
        assert_eq!(out.status.code(), Some(2), "{set}");
        assert!(stderr(&out).contains("hotend_c"), "{set}: {}", stderr(&out));
    }
    let out = sb.run(&["export", "ka", "--model", &run, "--format", "marlin", "--set", "layer_mm=50"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    for f in ["marlin", "klipper", "reprap", "c-header", "json"] {
        let out = sb.ok(&["export", "ka", "--model", &run, "--format", f, "--set", "layer_mm=0.2"]);
        assert!(!out.is_empty(), "{f}");
    }
    // No flow or acceleration input: the adaptive formats refuse (one K repeated is no table).
    let out = sb.run(&["export", "ka", "--model", &run, "--format", "orca", "--set", "layer_mm=0.2"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    // The run also stores the network as Burnpack; it loads into burn with the
    // weights of the JSON artifact.
    let rec = sb.json(&["runs", "show", &run]);
    let outputs = rec["stages"][0]["outputs"].as_array().expect("outputs");
    let hash_of = |name: &str| outputs.iter().find(|o| o["name"] == name).and_then(|o| o["hash"].as_str()).expect(name).to_string();
    let bpk = sb.run(&["cat", &hash_of("model.bpk")]).stdout;
    let json: serde_json::Value = serde_json::from_slice(&sb.run(&["cat", &hash_of("model.json")]).stdout).expect("model json");
    let weights: fdmlab_models::nets::NetWeights = serde_json::from_value(json["model"]["weights"].clone()).expect("weights");
    let hidden: Vec<usize> = weights.layers[1..].iter().map(|l| l.inputs).collect();
    let net = fdmlab_models::nets::ka::from_burnpack(&bpk, weights.layers[0].inputs, &hidden, &burn::prelude::Device::flex()).expect("load burnpack");
    assert_eq!(net.weights().expect("weights"), weights);
    // Same data, same seed: the same model artifacts (byte-identical).
    let again = sb.json(&["ka", "train", "--data", "t.csv", "--target", "k", "--epochs", "40", "--folds", "3"]);
    assert_eq!(again["model"], v["model"]);
    let again_rec = sb.json(&["runs", "show", again["run"].as_str().expect("run")]);
    assert_eq!(again_rec["stages"][0]["outputs"], rec["stages"][0]["outputs"]);
}

#[test]
fn spec_kind_runs_on_scored_prints() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "pa-prints.toml");
    for f in ["pa-data/pla-205.csv", "pa-data/pla-215.csv", "pa-data/pla-225.csv", "pa-data/petg-240.csv"] {
        let text = std::fs::read_to_string(crate::common::experiments().join(f)).expect("bundled scores");
        std::fs::create_dir_all(sb.path().join("pa-data")).expect("dir");
        sb.write(f, &text);
    }
    let out = sb.run(&["run", spec.to_str().expect("utf8 path")]);
    assert!(out.status.success(), "{}", stderr(&out));
    let files = sb.files();
    assert!(files.iter().any(|f| f.ends_with("reports/pa-prints/report.md")), "{files:?}");
    // Unknown key: located error, exit 2.
    let bad = sb.write("bad.toml", &std::fs::read_to_string(&spec).expect("spec").replace("[model]", "[model]\nwidth = 3"));
    let out = sb.run(&["validate", bad.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("width"));
}

#[test]
fn twin_grid_spec_meets_the_source_figure() {
    // The source reports a test deviation within 0.015 s. Here the bound applies to
    // every one of the 1,290 out-of-fold predictions of 5-fold CV (stricter than one
    // test split), and the network must beat every baseline's MAE.
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "pa-twin-grid.toml");
    let out = sb.run(&["run", spec.to_str().expect("utf8 path")]);
    assert!(out.status.success(), "{}", stderr(&out));
    let run = sb.json(&["runs", "show", "latest"]);
    let train = run["stages"].as_array().expect("stages").iter().find(|s| s["name"] == "train").expect("train stage");
    let m = &train["metrics"];
    let mlp_max = m["mlp_max_error"].as_f64().expect("mlp max");
    let mlp_mae = m["mlp_mae"].as_f64().expect("mlp mae");
    assert!(mlp_max <= 0.015, "max deviation {mlp_max}");
    for b in ["median", "linear", "knn"] {
        assert!(mlp_mae < m[format!("{b}_mae")].as_f64().expect("baseline mae"), "{b}");
    }
    let files = sb.files();
    assert!(files.iter().any(|p| p.ends_with("reports/pa-twin-grid/report.md")), "{files:?}");
}

/// Issue #29 items 3–5 by command: the twin's matrix → `ka fit` → `ka next` → the
/// adaptive exports; and the scored-prints path: matrix G-code → scores (drawn from the
/// nonlinear twin's line defects) → `ka scores --cells` → `ka fit`.
#[test]
fn adaptive_model_by_command_from_the_twin_and_from_scored_prints() {
    use fdmlab_models::adaptive::twin::TwinConfig;
    let sb = Sandbox::new();
    let v = sb.json(&["ka", "adaptive-grid", "-o", "cells.csv", "--seed", "5"]);
    assert_eq!(v["cells"], 12, "{v}");
    assert_eq!(v["generator"], "fdmlab-adaptive-twin/1");
    let fit = sb.json(&["ka", "fit", "--cells", "cells.csv", "--samples", "60"]);
    let run = fit["run"].as_str().expect("run id").to_string();
    let next = sb.json(&["ka", "next", "--model", &run, "--count", "2"]);
    let props = next["proposals"].as_array().expect("proposals");
    assert_eq!(props.len(), 2);
    assert_ne!(props[0], props[1]);
    let orca = sb.run(&["export", "ka", "--model", &run, "--format", "orca"]);
    assert!(orca.status.success(), "{}", stderr(&orca));
    let rows: Vec<Vec<f64>> = String::from_utf8_lossy(&orca.stdout).lines().map(|l| l.split(',').map(|x| x.parse().expect("number")).collect()).collect();
    assert_eq!(rows.len(), 12, "4 flows × 3 accelerations of the cells");
    // Monotone model: K does not rise with flow within an acceleration, nor with acceleration at a flow.
    for w in rows.windows(2).filter(|w| w[0][2] == w[1][2]) {
        assert!(w[1][0] <= w[0][0], "{w:?}");
    }
    for r in &rows[4..] {
        assert!(r[0] <= rows.iter().find(|x| x[1] == r[1] && x[2] < r[2]).expect("lower accel")[0]);
    }
    let kalico = sb.run(&["export", "ka", "--model", &run, "--format", "kalico"]);
    assert!(String::from_utf8_lossy(&kalico.stdout).contains("pressure_advance_model: tanh"), "{}", stderr(&kalico));
    let klipper = sb.run(&["export", "ka", "--model", &run, "--format", "klipper-adaptive"]);
    assert!(String::from_utf8_lossy(&klipper.stdout).contains("[gcode_macro FDMLAB_ADAPTIVE_PA]"));
    let marlin = sb.run(&["export", "ka", "--model", &run, "--format", "marlin"]);
    assert_eq!(marlin.status.code(), Some(2), "{}", stderr(&marlin));

    // Scored prints: 2 speeds × 2 accelerations, K lines 0–0.1 step 0.005.
    sb.json(&[
        "gcode",
        "pa",
        "--firmware",
        "klipper",
        "--k-end",
        "0.1",
        "--k-step",
        "0.005",
        "--slow-len",
        "10",
        "--speeds",
        "50,200",
        "--accels",
        "1000,4000",
        "--bed-mm",
        "350x350",
        "-o",
        "m.gcode",
    ]);
    let manifest: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("m.gcode.json")).expect("manifest")).expect("json");
    let mut csv = String::from("pattern,line,rater,score\n");
    let mut truth = Vec::new();
    for p in manifest["patterns"].as_array().expect("patterns") {
        let line: fdmlab_models::extrusion::LinePattern = serde_json::from_value(p["manifest"]["line"].clone()).expect("line");
        let twin = TwinConfig { slow_mm_s: line.slow_mm_s, slow_len_mm: line.slow_len_mm, fast_len_mm: line.fast_len_mm, ..TwinConfig::default() };
        let c = twin.conditions[0];
        let (v, a) = (p["speed_mm_s"].as_f64().expect("v"), p["accel_mm_s2"].as_f64().expect("a"));
        for (i, r) in p["manifest"]["regions"].as_array().expect("regions").iter().enumerate() {
            let s = fdmlab_models::extrusion::scoring::ideal_score(twin.defect(&c, v, a, r["k"].as_f64().expect("k")).expect("defect"));
            // Two raters, one a point harsher: whole points as people give them.
            csv += &format!("{},{},ann,{}\n{},{},bob,{}\n", p["index"], i + 1, s.round(), p["index"], i + 1, (s - 1.0).round().max(0.0));
        }
        truth.push((p["flow_mm3_s"].as_f64().expect("flow"), a, twin.optimal_k(&c, v, a).expect("truth")));
    }
    sb.write("m.csv", &csv);
    sb.json(&["ka", "scores", "--manifest", "m.gcode.json", "--scores", "m.csv", "--cells", "c.csv"]);
    let cells = std::fs::read_to_string(sb.path().join("c.csv")).expect("cells");
    assert!(cells.starts_with("flow_mm3_s,accel_mm_s2,k,k_sd,layer_mm,hotend_c,material\n"), "{cells}");
    let fit = sb.json(&["ka", "fit", "--cells", "c.csv", "--samples", "60"]);
    let run = fit["run"].as_str().expect("run").to_string();
    let orca = sb.run(&["export", "ka", "--model", &run, "--format", "orca", "--set", "layer_mm=0.2"]);
    assert!(orca.status.success(), "{}", stderr(&orca));
    // The exported K at each printed cell against the twin's noiseless best K (the one that
    // minimises the widest width error). Lines 0.005 s apart scored in whole points put the
    // parabola's vertex within about a quarter step (1.25 ms) — but the score curve is not
    // symmetric about that K (the width error grows faster on one side), so the vertex leans
    // high: 2.2 ms at 200 mm/s, 1000 mm/s² on the first run, as the twin's own matrix shows
    // (up to 1.4 ms with 0.00025 s fine steps, docs/pressure-advance.md). Bound: 3 ms, 6 % of K.
    let rows: Vec<Vec<f64>> = String::from_utf8_lossy(&orca.stdout).lines().map(|l| l.split(',').map(|x| x.parse().expect("number")).collect()).collect();
    for r in &rows {
        let t = truth.iter().find(|t| (t.0 - r[1]).abs() < 1e-9 && t.1 == r[2]).expect("a printed cell");
        assert!((r[0] - t.2).abs() < 0.003, "flow {} accel {}: K {} vs twin {}", r[1], r[2], r[0], t.2);
    }
    // And K falls with flow at both accelerations, as the twin's does.
    assert!(rows[1][0] < rows[0][0] && rows[3][0] < rows[2][0], "{rows:?}");
}

/// Issue #29 item 7: the bundled `pa-adaptive` spec on the twin, checked against the
/// twin's known parameters (its noiseless best K per pattern, its K₂ = −r·K) and against
/// OrcaSlicer's own interpolation of the exported rows.
#[test]
fn pa_adaptive_spec_recovers_the_twin_and_orca_reads_its_table() {
    use fdmlab_models::adaptive::twin::{TwinCell, TwinConfig};
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "pa-adaptive.toml");
    let out = sb.run(&["run", spec.to_str().expect("utf8 path")]);
    assert!(out.status.success(), "{}", stderr(&out));
    let run = sb.json(&["runs", "show", "latest"]);
    let get = |stage: &str, name: &str| {
        let s = run["stages"].as_array().expect("stages").iter().find(|s| s["name"] == stage).expect(stage);
        let hash = s["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == name).and_then(|o| o["hash"].as_str()).expect(name);
        sb.run(&["cat", hash]).stdout
    };
    let cells: Vec<TwinCell> = serde_json::from_slice(&get("twin", "cells.json")).expect("cells");
    assert_eq!(cells.len(), 12, "Orca's guide grid: 4 speeds × 3 accelerations");
    let art = fdmlab_datasets::pa::kflow::KflowArtifact::from_json(&get("fit", "model.json"), "model.json").expect("model");
    let q = |f: f64, a: f64| fdmlab_models::adaptive::model::Query {
        flow_mm3_s: f,
        accel_mm_s2: a,
        layer_mm: Some(0.2),
        hotend_c: Some(215.0),
        material: Some("PLA".into()),
    };
    // Model vs the twin's noiseless best K at every printed pattern. The measured cells lean
    // high of it by up to ~1.4 ms (asymmetric score curve, docs/pressure-advance.md) and the
    // model follows its cells: bound 2 ms, 4 % of K.
    for c in &cells {
        let k = art.model.predict(&q(c.flow_mm3_s, c.accel_mm_s2)).expect("predict").k;
        assert!((k - c.k_true).abs() < 0.002, "{} mm/s, {} mm/s²: model {k} vs twin {}", c.speed_mm_s, c.accel_mm_s2, c.k_true);
    }
    // The twin's K falls by 10–20 % from 4.8 to 19.2 mm³/s (nonlinear pressure); so does the model's.
    for a in [1000.0, 2000.0, 4000.0] {
        let (lo, hi) = (art.model.predict(&q(4.8, a)).expect("lo").k, art.model.predict(&q(19.2, a)).expect("hi").k);
        assert!(hi < 0.9 * lo, "accel {a}: {lo} → {hi}");
    }
    // Residuals through the discrepancy workflow: the missing effect is named, K₂ near the twin's.
    let lines: serde_json::Value = serde_json::from_slice(&get("lines", "lines.json")).expect("lines");
    assert!(lines["named"].as_array().expect("named").iter().any(|n| n == "nonlinear_pressure"), "{lines}");
    let twin = TwinConfig::default();
    let k2_true = twin.plant(&cells[0].conditions).k2_s2_per_mm3;
    assert!((k2_true + 0.016 * twin.plant(&cells[0].conditions).k_s).abs() < 1e-12, "the spec's K₂ = −0.016·K");
    let k2 = lines["k2_s2_per_mm3"].as_f64().expect("k2");
    // 10 %: two lines of ~1,500 sensor samples at 0.02 mm³/s noise pin K₂ to a few %.
    assert!((k2 - k2_true).abs() < 0.1 * k2_true.abs(), "K₂ {k2} vs twin {k2_true}");
    // Prints vs error on held-out seeds: chosen patterns beat the grid's order at 3–6 prints;
    // 5 chosen do not quite reach the full grid (1.33×; < 2× asserted, the target is 1×).
    let design: serde_json::Value = serde_json::from_slice(&get("design", "design.json")).expect("design");
    let rows = design["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 12);
    for r in &rows[2..6] {
        assert!(r["chosen_rms_s"].as_f64() < r["grid_rms_s"].as_f64(), "{r}");
    }
    assert!(design["ratio_at_5"].as_f64().expect("ratio") < 2.0, "{design}");
    // Orca: its PCHIP (flow, then acceleration, 3 decimals) of the exported rows vs the model
    // off the grid. Bound 1.5 ms: rows rounded to 0.05 ms, Orca's output to 0.5 ms, and the
    // interpolation error between flow nodes 4.8 mm³/s apart where K bends by < 1 ms.
    let rows = String::from_utf8(get("export", "ka-orca.txt")).expect("utf8");
    for f in [6.1, 11.7, 17.3] {
        for a in [1300.0, 2900.0, 3700.0] {
            let orca = crate::orca_pchip::orca_interpolate(&rows, f, a);
            let k = art.model.predict(&q(f, a)).expect("predict").k;
            assert!((orca - k).abs() < 0.0015, "flow {f}, accel {a}: Orca {orca} vs model {k}");
        }
    }
    let kalico = String::from_utf8(get("export", "ka-kalico.cfg")).expect("utf8");
    assert!(kalico.contains("pressure_advance_model: tanh") && kalico.contains("SET_PRESSURE_ADVANCE MODEL=tanh"), "{kalico}");
    assert!(String::from_utf8(get("export", "ka-klipper-adaptive.cfg")).expect("utf8").contains("[gcode_macro FDMLAB_ADAPTIVE_PA]"));
    assert!(sb.files().iter().any(|p| p.ends_with("reports/pa-adaptive/report.md")));
    // A held-out seed equal to the experiment's is refused, naming the key.
    let bad = sb.write("bad.toml", &std::fs::read_to_string(&spec).expect("spec").replace("seeds = [31, 32]", "seeds = [7, 32]"));
    let out = sb.run(&["validate", bad.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("design.seeds"), "{}", stderr(&out));
}
