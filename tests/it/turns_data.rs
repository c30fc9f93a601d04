//! Turn corpus, streaming reader, planner and baselines end to end (issue #12 §1–§4).

use crate::common::Sandbox;
use fdmlab_datasets::turns::{open, read_moves, shipped_corpus, Manifest};
use fdmlab_models::turns::junctions;
use fdmlab_models::turns::planner::{late_summary, PlannerParams};
use std::io::Read;

fn corpus() -> (std::path::PathBuf, Manifest) {
    let dir = shipped_corpus();
    let m = Manifest::read(&dir).expect("shipped manifest reads");
    (dir, m)
}

#[test]
fn every_corpus_file_streams_and_matches_its_manifest() {
    let (dir, m) = corpus();
    let slicers: std::collections::BTreeSet<&str> = m.files.iter().map(|f| f.slicer.as_str()).collect();
    assert_eq!(slicers.into_iter().collect::<Vec<_>>(), vec!["cura-engine", "prusa-slicer", "slic3r", "synthetic"]);
    // Split by family: no family, and so no model, in two splits; every slicer in each.
    let mut split_of = std::collections::BTreeMap::new();
    for f in &m.files {
        let model = f.model["name"].as_str().unwrap_or_default();
        for key in [format!("family {}", f.family), format!("model {model}")] {
            let seen = split_of.entry(key.clone()).or_insert(f.split.clone());
            assert_eq!(*seen, f.split, "{key} is in two splits ({})", f.file);
        }
    }
    for split in ["train", "tune", "test"] {
        let slicers: std::collections::BTreeSet<&str> = m.files.iter().filter(|f| f.split == split).map(|f| f.slicer.as_str()).collect();
        assert!(["prusa-slicer", "slic3r", "cura-engine"].iter().all(|s| slicers.contains(s)), "{split}: {slicers:?}");
    }
    for f in &m.files {
        let path = dir.join(&f.file);
        let mut bytes = Vec::new();
        open(&path).expect("opens").read_to_end(&mut bytes).expect("decompresses");
        assert_eq!(bytes.len() as u64, f.gcode_bytes, "{}", f.file);
        let moves = read_moves(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(moves.len() > 100, "{}: {} moves", f.file, moves.len());
        // Layers never go back.
        assert!(moves.windows(2).all(|w| w[0].layer <= w[1].layer), "{}", f.file);
    }
}

#[test]
fn the_manifests_split_check_names_a_family_in_two_splits() {
    // `Manifest::check_splits` (what a full corpus built outside the repository
    // is checked with, as build.py checks it): the shipped manifest passes; move
    // one file of a training family to test and it names the family and both files.
    let (dir, mut m) = corpus();
    m.check_splits(&dir).expect("the shipped splits are disjoint");
    let first = m.files.iter().position(|f| f.split == "train").expect("a training file");
    let family = m.files[first].family.clone();
    let other = m.files.iter().rposition(|f| f.family == family).expect("the family's last file");
    assert_ne!(first, other, "the family has two files");
    m.files[other].split = "test".into();
    let err = m.check_splits(&dir).expect_err("a family in two splits").to_string();
    assert!(err.contains(&format!("family {family} is in splits train")) && err.contains(&m.files[other].file), "{err}");
}

#[test]
fn the_reader_names_each_slicer_from_its_header() {
    let (dir, m) = corpus();
    for slicer in ["prusa-slicer", "slic3r", "cura-engine", "synthetic"] {
        let f = m.files.iter().find(|f| f.slicer == slicer).expect("a file of each slicer");
        assert_eq!(fdmlab_datasets::turns::slicer_of(&dir.join(&f.file)).expect("reads"), slicer, "{}", f.file);
    }
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/testdata/slicers");
    for (file, slicer) in
        [("orcaslicer", "orcaslicer"), ("bambu-studio", "bambu-studio"), ("superslicer", "superslicer"), ("cura", "cura-engine"), ("simplify3d", "simplify3d")]
    {
        assert_eq!(fdmlab_datasets::turns::slicer_of(&fixtures.join(format!("{file}.gcode"))).expect("reads"), slicer);
    }
}

#[test]
fn the_bundled_specs_splits_follow_the_manifests_families() {
    // experiments/turn-prediction.toml trains, tunes and tests on files of the
    // manifest's train, tune and test splits, so its families are disjoint.
    let (_, m) = corpus();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("experiments/turn-prediction.toml");
    let spec: fdmlab_pipeline::kinds::turn_prediction::TurnSpec = fdmlab_pipeline::spec::SpecFile::load(&path).and_then(|s| s.parse()).expect("spec");
    let mut families = std::collections::BTreeMap::new();
    for (split, files) in [("train", &spec.data.train), ("tune", &spec.data.tune), ("test", &spec.data.test)] {
        assert!(!files.is_empty(), "{split}");
        for f in files {
            let name = f.rsplit('/').next().expect("path");
            let rec = m.files.iter().find(|r| r.file == name).unwrap_or_else(|| panic!("{name} not in the manifest"));
            assert_eq!(rec.split, split, "{name}");
            assert_eq!(*families.entry(rec.family.clone()).or_insert(split), split, "family {} in two splits", rec.family);
        }
    }
}

#[test]
fn synthetic_arcs_become_chords_on_their_circles() {
    let (dir, m) = corpus();
    let f = m.files.iter().find(|f| f.slicer == "synthetic").expect("an arc program");
    let moves = read_moves(&dir.join(&f.file)).expect("reads");
    let text = {
        let mut s = String::new();
        open(&dir.join(&f.file)).expect("opens").read_to_string(&mut s).expect("text");
        s
    };
    // Every G2/G3 line yields several chords carrying its line number.
    let arc_lines: Vec<usize> = text.lines().enumerate().filter(|(_, l)| l.starts_with("G2 ") || l.starts_with("G3 ")).map(|(i, _)| i + 1).collect();
    assert!(!arc_lines.is_empty());
    for line in arc_lines {
        assert!(moves.iter().filter(|m| m.line == line).count() >= 4, "line {line}");
    }
    // Consecutive chords of an arc turn by Δθ = 2·acos(1 − 0.005/r) ≤ 11.5° for r ≥ 1 mm (the generator's smallest radius).
    let j = junctions(&moves);
    let chord_turns = j.iter().zip(moves.windows(2)).filter(|(_, w)| w[0].line == w[1].line).map(|(j, _)| j.turn_deg);
    assert!(chord_turns.fold(0.0, f64::max) < 11.5);
}

#[test]
#[ignore = "the issue's premise, not reproduced (disputed in the #12 note): measured 10 of 198,644 sharp corners (> 45°) of the slicer-made corpus enter Marlin's 16-block buffer after an unlimited-lookahead planner at 500 mm/s, 1000 mm/s² is already braking for them; the digest's 'too late' is not reproduced with Marlin's buffer (slicer moves are too short to reach speeds that brake over 16 moves); with 4 or 2 blocks corners are late (7 % and 14 % of the held-out files'), and the network's calls lower the line width most (docs/turns.md, Downstream)"]
fn most_sharp_corners_of_real_slicer_output_enter_the_buffer_too_late() {
    // The digest (shared/reference/pressure_advance.md, "lag"): at 500 mm/s and
    // 1000 mm/s² most sharp corners reach Marlin's 16-block buffer too late to
    // decelerate. Over every slicer-made file of the corpus.
    let (dir, m) = corpus();
    let p = PlannerParams { speed_mm_s: Some(500.0), max_speed_mm_s: 500.0, max_accel_mm_s2: 1000.0, ..PlannerParams::marlin() }.check().expect("valid");
    let (mut sharp, mut late) = (0, 0);
    for f in m.files.iter().filter(|f| f.slicer != "synthetic") {
        let moves = read_moves(&dir.join(&f.file)).expect("reads");
        let s = late_summary(&junctions(&moves), &p.knowledge(&moves), 45.0);
        sharp += s.sharp;
        late += s.too_late;
    }
    assert!(sharp > 10_000, "{sharp} sharp corners");
    assert!(late * 2 > sharp, "{late} of {sharp} sharp corners too late");
    // With the slicers' own speeds the same buffer is mostly in time: the lag is a high-speed problem.
    let own = PlannerParams::marlin().check().expect("valid");
    let f = m.files.iter().find(|f| f.slicer == "prusa-slicer").expect("a PrusaSlicer file");
    let moves = read_moves(&dir.join(&f.file)).expect("reads");
    let s = late_summary(&junctions(&moves), &own.knowledge(&moves), 45.0);
    assert!(s.fraction.is_some_and(|x| x < 0.5), "{s:?}");
}

#[test]
fn cli_reads_plans_and_scores_corpus_files() {
    let sb = Sandbox::new();
    let (dir, m) = corpus();
    let file = dir.join(&m.files.iter().find(|f| f.slicer == "cura-engine").expect("a Cura file").file);
    let file = file.to_str().expect("utf8 path");
    let v = sb.json(&["turns", "moves", file, "--out", "j.csv"]);
    let moves = read_moves(std::path::Path::new(file)).expect("reads");
    assert_eq!(v["moves"].as_u64(), Some(moves.len() as u64));
    let csv = std::fs::read_to_string(sb.path().join("j.csv")).expect("csv written");
    assert_eq!(csv.lines().count(), moves.len()); // header + one row per junction
    let v = sb.json(&["turns", "planner", file, "--speed", "500"]);
    assert!(v["summary"]["sharp"].as_u64().is_some_and(|n| n > 0));
    assert!(v["buffered_duration_s"].as_f64() >= v["unlimited_duration_s"].as_f64());
    let train = dir.join(&m.files.iter().find(|f| f.split == "train" && f.slicer == "prusa-slicer").expect("train file").file);
    let v = sb.json(&["turns", "baselines", file, "--horizon", "16", "--train", train.to_str().expect("utf8")]);
    let names: Vec<&str> = v["baselines"].as_array().expect("rows").iter().filter_map(|r| r["name"].as_str()).collect();
    assert_eq!(names, ["no_turn", "last_turn", "previous_layer", "knn", "planner"]);
}

#[test]
fn bad_gcode_and_missing_files_exit_2_naming_file_and_line() {
    let sb = Sandbox::new();
    let bad = sb.write("bad.gcode", "G90\nG1 X1 Y1\nG2 X5 Y5\n");
    let out = sb.run(&["turns", "moves", bad.to_str().expect("utf8")]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.gcode:3: G2/G3: an arc needs I/J or R"), "{err}");
    let out = sb.run(&["turns", "planner", "nope.gcode"]);
    assert_eq!(out.status.code(), Some(2));
    let out = sb.run(&["turns", "planner", bad.to_str().expect("utf8"), "--blocks", "1"]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn reader_bench_runs_on_the_corpus() {
    // Not a timing test: the bench's plumbing, on 1 MB.
    let sb = Sandbox::new();
    let corpus = shipped_corpus();
    let v = sb.json(&["bench", "turns", "--corpus", corpus.to_str().expect("utf8"), "--mb", "1"]);
    assert!(v["file_bytes"].as_u64().is_some_and(|b| b >= 1_000_000));
    assert!(v["moves"].as_u64().is_some_and(|n| n > 1000));
}
