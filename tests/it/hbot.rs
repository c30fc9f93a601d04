//! H-Bot and Taguchi commands end to end: arrays, analysis, twin simulation,
//! G-code → step streams, the `hbot-taguchi` spec kind, and bad input refused.

use crate::common::{copy_spec, stderr, Sandbox};

const SPEC: &str = "hbot-taguchi.toml";

#[test]
fn taguchi_array_l27_five_factors() {
    let sb = Sandbox::new();
    let v = sb.json(&["taguchi", "array", "L27", "--factors", "5"]);
    assert_eq!(v["runs"], 27);
    assert_eq!(v["columns"], serde_json::json!([1, 2, 5, 9, 10]));
    assert_eq!(v["orthogonal"], true);
    assert_eq!(v["rows"][26], serde_json::json!([3, 3, 3, 1, 3]));
    let out = sb.run(&["taguchi", "array", "L12"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    // Names that would break the template `taguchi analyze` reads back.
    for names in ["a,a,c", "run,b,c", "a,s,c", "a,b c,d"] {
        let out = sb.run(&["taguchi", "array", "L9", "--factors", "3", "--names", names, "--csv", "t.csv"]);
        assert_eq!(out.status.code(), Some(2), "{names}: {}", stderr(&out));
        assert!(!sb.path().join("t.csv").exists());
    }
}

/// Yang & El-Haik (2003), Design for Six Sigma §13.4: L9, A/B/C on columns 1/2/4,
/// larger is better; published SS_A = 158, contributions A 87.78 %, C 10.37 %, optimum A3 C2.
const L9_RESULTS: &str = "run,A,B,C,y\n1,1,1,1,8\n2,1,2,2,12\n3,1,3,3,9\n4,2,1,3,11\n5,2,2,1,12\n6,2,3,2,15\n7,3,1,2,21\n8,3,2,3,18\n9,3,3,1,20\n";

#[test]
fn taguchi_analyze_reproduces_a_published_example() {
    let sb = Sandbox::new();
    sb.write("l9.csv", L9_RESULTS);
    let v = sb.json(&["taguchi", "analyze", "l9.csv", "--response", "y", "--larger-better"]);
    let keys: Vec<&str> = v.as_object().expect("object").keys().map(String::as_str).collect();
    assert_eq!(keys, ["anova", "factors", "optimum"]);
    assert_eq!(v["optimum"], serde_json::json!({"A": 3, "B": 3, "C": 2}));
    let a = &v["factors"][0];
    assert_eq!(a.as_object().expect("factor").len(), 4, "{a}");
    assert_eq!(a["rank"], 1);
    // k_A3 = (21 + 18 + 20)/3 exactly as printed.
    assert!((a["level_means"][2].as_f64().expect("k3") - 59.0 / 3.0).abs() < 1e-12);
    // Published to two decimals.
    assert!((v["anova"][0]["percent"].as_f64().expect("pct") - 87.78).abs() < 5e-3);
    assert!((v["anova"][2]["percent"].as_f64().expect("pct") - 10.37).abs() < 5e-3);
}

#[test]
fn taguchi_analyze_l27_with_the_five_source_factors() {
    // The source's design (T0, Kt, J_M, b_bridge, Fc_bridge at three levels in
    // L27) with a known additive response s = 0.1 + Σ effect(level): in an
    // orthogonal array each level mean is exactly 0.1 + that effect, the range
    // ranks the factors, the smallest effect is the optimum level, and each
    // factor's sum of squares is 9·Σ effect² (zero-mean effects, no error).
    let effects: [(&str, [f64; 3]); 5] = [
        ("T0", [0.02, -0.015, -0.005]),
        ("Kt", [-0.03, 0.0, 0.03]),
        ("J_M", [0.005, -0.004, -0.001]),
        ("b_bridge", [0.001, -0.002, 0.001]),
        ("Fc_bridge", [-0.006, 0.01, -0.004]),
    ];
    let sb = Sandbox::new();
    let array = sb.json(&["taguchi", "array", "L27", "--factors", "5"]);
    let mut csv = format!("run,{},s\n", effects.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(","));
    for (i, row) in array["rows"].as_array().expect("rows").iter().enumerate() {
        let levels: Vec<usize> = row.as_array().expect("row").iter().map(|l| l.as_u64().expect("level") as usize).collect();
        let s: f64 = 0.1 + levels.iter().zip(&effects).map(|(&l, (_, e))| e[l - 1]).sum::<f64>();
        csv += &format!("{},{},{s}\n", i + 1, levels.iter().map(|l| l.to_string()).collect::<Vec<_>>().join(","));
    }
    sb.write("l27.csv", &csv);
    let v = sb.json(&["taguchi", "analyze", "l27.csv"]);
    assert_eq!(v["optimum"], serde_json::json!({"T0": 2, "Kt": 1, "J_M": 2, "b_bridge": 2, "Fc_bridge": 1}));
    let ss: Vec<f64> = effects.iter().map(|(_, e)| 9.0 * e.iter().map(|x| x * x).sum::<f64>()).collect();
    let total: f64 = ss.iter().sum();
    for (i, ((name, e), rank)) in effects.iter().zip([2, 1, 4, 5, 3]).enumerate() {
        let f = &v["factors"][i];
        for l in 0..3 {
            assert!((f["level_means"][l].as_f64().expect("k") - (0.1 + e[l])).abs() < 1e-12, "{name} k{}", l + 1);
        }
        assert_eq!(f["rank"], rank, "{name}");
        assert!((v["anova"][i]["percent"].as_f64().expect("percent") - 100.0 * ss[i] / total).abs() < 1e-6, "{name}");
    }
}

#[test]
fn taguchi_analyze_names_the_bad_cell() {
    let sb = Sandbox::new();
    sb.write("bad.csv", "A,B,s\n1,1,0.1\n2,7,0.2\n");
    let out = sb.run(&["taguchi", "analyze", "bad.csv", "--json"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("bad.csv:3: B: `7` is not a level 1..=3"), "{}", stderr(&out));
}

#[test]
fn hbot_simulate_reproduces_the_source_shortfall_and_writes_files() {
    let sb = Sandbox::new();
    let v = sb.json(&["hbot", "simulate", "--duration-s", "0.75"]);
    // Drive stiffness calibrated on the source's 7.867 mm (8 mm in 0.75 s); ±0.01 mm.
    let y = v["y_at_stop_mm"].as_f64().expect("y");
    assert!((y - 7.867).abs() < 0.01, "{v}");
    assert_eq!(v["x_at_stop_mm"], 0.0);
    let csv = sb.ok(&["hbot", "simulate", "--axis", "x", "--duration-s", "0.25", "--settle-s", "0"]);
    assert!(csv.starts_with("t_s,x_mm,y_mm"));
    assert_eq!(csv.lines().count(), 27);
    sb.json(&["hbot", "simulate", "--out", "traj.parquet"]);
    let bytes = std::fs::read(sb.path().join("traj.parquet")).expect("parquet written");
    assert_eq!(&bytes[..4], b"PAR1");
    // Staged writes are renamed into place: outside the store only the output is left
    // (a staged file is `.fdmlab-w…`; the old check looked for `.tmp`, which never exists).
    let outside: Vec<String> = sb.files().into_iter().filter(|f| !f.starts_with("store/")).collect();
    assert_eq!(outside, ["traj.parquet"]);
    let out = sb.run(&["hbot", "simulate", "--set", "m_bridge=-1"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
}

#[test]
fn hbot_steps_converts_m11_gcode_and_refuses_leaving_the_bed() {
    let sb = Sandbox::new();
    sb.write("grad.gcode", "G28\nM83\nG1 X10 Y10 F3000\nM11 F0.5 S0.2\nG1 X20 Y10 E1\nM11 F0 S1\nG1 X20 Y20 E1\n");
    let csv = sb.ok(&["hbot", "steps", "grad.gcode"]);
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], "line,ticks,duration_s,M1,M2,Z,E0,E1,E2");
    assert!(lines[2].ends_with(",800,800,0,47,18,28"), "{csv}");
    assert!(lines[3].ends_with(",800,-800,0,0,93,0"), "{csv}");
    let v = sb.json(&["hbot", "steps", "grad.gcode", "--ticks", "--out", "ticks.csv"]);
    assert_eq!(v["mix_changes"], 2);
    let ticks = std::fs::read_to_string(sb.path().join("ticks.csv")).expect("ticks");
    assert_eq!(ticks.lines().count(), 1 + 1600 + 800 + 800);
    sb.write("off.gcode", "G1 X10 Y10\nG1 X300 Y10\n");
    let out = sb.run(&["hbot", "steps", "off.gcode", "--out", "off.csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("off.gcode:2: X: X300 leaves the bed"), "{}", stderr(&out));
    assert!(!sb.path().join("off.csv").exists());
}

#[test]
fn hbot_taguchi_spec_identifies_and_compensates() {
    let sb = Sandbox::new();
    let run = &sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")])[0];
    let stages: Vec<&str> = run["stages"].as_array().expect("stages").iter().map(|s| s["name"].as_str().expect("name")).collect();
    assert_eq!(stages, ["measure", "screen", "taguchi", "direct", "compensate", "report"]);
    let m = &run["stages"][4]["metrics"];
    // The bar: compensation cuts the mean absolute error at least 5×.
    let (before, after) = (m["mae_before_mm"].as_f64().expect("before"), m["mae_after_mm"].as_f64().expect("after"));
    assert!(after * 5.0 <= before, "{m}");
    // The direct fit reaches the laser's noise floor on the held-out move (mean |noise| ≈ 1.6 µm).
    assert!(run["stages"][3]["metrics"]["verify_direct_s_mm"].as_f64().expect("s") < 0.0025, "{}", run["stages"][3]);
    let report = sb.files().into_iter().find(|f| f.ends_with("hbot-taguchi/report.md")).expect("report.md");
    let text = std::fs::read_to_string(sb.path().join(report)).expect("read report");
    assert!(text.contains("k1") && text.contains("Identified parameters") && text.contains("Mean absolute positioning error"));
}

#[test]
fn hbot_spec_errors_are_located() {
    let sb = Sandbox::new();
    let text = std::fs::read_to_string(crate::common::experiments().join(SPEC)).expect("spec");
    let spec = sb.write("bad.toml", &text.replace("Fc_cart = 0.32", "Fc_kart = 0.32"));
    let out = sb.run(&["run", spec.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("truth.Fc_kart"), "{}", stderr(&out));
    let spec = sb.write("bad2.toml", &text.replace("iterations = 3", "iterations = 0"));
    let out = sb.run(&["run", spec.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
}
