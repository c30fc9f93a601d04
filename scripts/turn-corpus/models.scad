// Parametric models of the turn corpus (issue #12 §4). Rendered headless:
//   openscad -D 'kind="polygon"' -D n=7 -D size=24 -D height=6 -o out.stl models.scad
// Every parameter is set by build.py from its seed and recorded in the manifest.
kind = "polygon";
n = 6;          // polygon sides / count of bosses, fins or waves
size = 24;      // footprint, mm
height = 6;     // mm
wall = 1.2;     // wall / fin thickness, mm
angle = 45;     // overhang angle, degrees
label = "FDM";
depth = 0.6;    // engraving depth, mm

module polygon_prism() {
    difference() {
        cylinder(r = size / 2, h = height, $fn = n);
        translate([0, 0, -1]) rotate(180 / n) cylinder(r = size / 4, h = height + 2, $fn = max(3, n * 2));
    }
}

module text_block() {
    linear_extrude(height) text(label, size = size / max(1, len(label)) * 1.3, halign = "center", valign = "center");
}

module bosses() {
    translate([-size / 2, -size / 3, 0]) cube([size, size * 2 / 3, 1.6]);
    for (i = [0 : n - 1]) {
        x = -size / 2 + size * (i + 0.5) / n;
        translate([x, (i % 2 == 0 ? -1 : 1) * size / 8, 0]) difference() {
            cylinder(r = size / (2.6 * n) + 1.2, h = height, $fn = 40);
            translate([0, 0, 1]) cylinder(r = size / (5 * n), h = height, $fn = 24);
        }
    }
}

module overhang() {
    // A wall leaning out at `angle` from vertical, on a foot.
    translate([-size / 2, -size / 4, 0]) cube([size, size / 2, 1.6]);
    multmatrix([[1, 0, tan(angle), 0], [0, 1, 0, 0], [0, 0, 1, 0]]) translate([-size / 2, -wall * 2, 0]) cube([size / 2, wall * 4, height]);
    translate([size / 8, -size / 4, 0]) cube([size / 3, size / 2, height / 2]);
    translate([size / 8, -size / 4, height / 2]) cube([size / 2.2, size / 2, 1.2]);
}

module curved_wall() {
    // A wavy wall of `n` waves and a quarter-round tube.
    pts = [for (i = [0 : 120]) let(t = i / 120) [size * (t - 0.5), size / 6 * sin(360 * n * t / 2)]];
    linear_extrude(height) union() {
        for (i = [0 : 119]) hull() {
            translate(pts[i]) circle(d = wall, $fn = 12);
            translate(pts[i + 1]) circle(d = wall, $fn = 12);
        }
    }
    translate([0, size / 3, 0]) linear_extrude(height) difference() {
        circle(r = size / 3, $fn = 90);
        circle(r = size / 3 - wall, $fn = 90);
        translate([-size, -2 * size]) square([2 * size, 2 * size]);
    }
}

module thin_features() {
    translate([-size / 2, -size / 4, 0]) cube([size, size / 2, 1.2]);
    for (i = [0 : n - 1]) {
        w = wall * (0.4 + 0.6 * i / max(1, n - 1));
        translate([-size / 2 + size * (i + 0.5) / n - w / 2, -size / 4, 0]) cube([w, size / 2, height]);
    }
}

module lattice() {
    // A flat lattice panel: a frame around n × n cells of one of three shapes.
    cell = size / n;
    linear_extrude(height) difference() {
        square([size, size], center = true);
        for (i = [0 : n - 1], k = [0 : n - 1])
            translate([-size / 2 + cell * (i + 0.5), -size / 2 + cell * (k + 0.5)])
                rotate(angle) circle(d = cell - wall, $fn = (i + k) % 3 == 0 ? 6 : (angle > 40 ? 4 : 32));
    }
}

module engraving() {
    // Small text cut `depth` deep into a plate.
    difference() {
        translate([-size / 2, -size / 4, 0]) cube([size, size / 2, height]);
        translate([0, 0, height - depth]) linear_extrude(depth + 1)
            text(label, size = size / max(1, len(label)) * 0.9, halign = "center", valign = "center");
    }
}

if (kind == "polygon") polygon_prism();
else if (kind == "text") text_block();
else if (kind == "bosses") bosses();
else if (kind == "overhang") overhang();
else if (kind == "curved_wall") curved_wall();
else if (kind == "thin_features") thin_features();
else if (kind == "lattice") lattice();
else if (kind == "engraving") engraving();
