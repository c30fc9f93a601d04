//! CSV of the twin's measured grid: the K_A data set the source collected by hand.

use fdmlab_models::extrusion::GridRow;

/// Columns of the data CSV (inputs then the measured target `k_a`).
pub const GRID_HEADER: &str = "material,extruder,hotend_c,bed_c,nozzle_setting_mm,layer_mm,k_a";

/// The data set as a person would have it: conditions and measured K_A only.
pub fn grid_csv(rows: &[GridRow]) -> String {
    let mut s = String::with_capacity(rows.len() * 48);
    s.push_str(GRID_HEADER);
    s.push('\n');
    for r in rows {
        let c = &r.conditions;
        s.push_str(&format!("{},{},{},{},{},{},{}\n", c.material.name(), c.extruder.name(), c.hotend_c, r.bed_c, c.nozzle_setting_mm, c.layer_mm, r.k_a));
    }
    s
}

/// The twin's side of the same rows (row order matches [`grid_csv`]): the true K and
/// the measurement's standard uncertainty — kept apart so it cannot leak into training.
pub fn truth_csv(rows: &[GridRow]) -> String {
    let mut s = String::from("row,k_true,k_a_sd\n");
    for (i, r) in rows.iter().enumerate() {
        s.push_str(&format!("{},{},{}\n", i + 1, r.k_true, r.k_a_sd));
    }
    s
}
