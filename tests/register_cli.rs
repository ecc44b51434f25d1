//! `helmcap register` end to end: an OBJ template onto a remeshed, moved PLY scan.

#![allow(clippy::unwrap_used)]

use helmcap::mesh::{Mesh, read_obj_positions, write_obj, write_ply};
use nalgebra::{Point3, Rotation3, Translation3, Vector3};

mod common;
use common::helmcap;

/// A bumpy height field over [0, 80]² mm on an `n × n` grid, as triangles.
fn surface(n: usize, squash: f64) -> Mesh {
    let h = |x: f64, y: f64| squash * 6.0 * (x * 0.09).sin() * (y * 0.07).cos();
    let step = 80.0 / n as f64;
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 * step, j as f64 * step);
            positions.push(Point3::new(x, y, h(x, y)));
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut tris = Vec::new();
    for j in 0..n {
        for i in 0..n {
            tris.push(vec![id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push(vec![id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Mesh::new(positions, &tris, Vec::new(), None).unwrap()
}

#[test]
fn register_fits_a_template_onto_a_ply_scan() {
    let dir = tempfile::tempdir().unwrap();
    let motion =
        Translation3::new(10.0, 5.0, -20.0) * Rotation3::from_axis_angle(&Vector3::x_axis(), 0.3);
    // Template: the surface with its bumps 25 % lower; scan: the true surface, finer grid.
    let template = surface(24, 0.75);
    let truth = surface(24, 1.0);
    let mut scan = surface(37, 1.0);
    for p in &mut scan.positions {
        *p = motion * *p;
    }
    let t_path = dir.path().join("template.obj");
    let s_path = dir.path().join("scan.ply");
    let l_path = dir.path().join("landmarks.csv");
    let out = dir.path().join("registered.obj");
    write_obj(&t_path, &template).unwrap();
    write_ply(&s_path, &scan, None).unwrap();
    let mut csv = String::from("vertex,x,y,z\n");
    for v in [0usize, 24, 25 * 24, 25 * 25 - 1, 12 * 25 + 12] {
        let p = motion * truth.positions[v];
        csv += &format!("{v},{},{},{}\n", p.x, p.y, p.z);
    }
    std::fs::write(&l_path, csv).unwrap();
    let o = helmcap(&[
        "register",
        "--template",
        t_path.to_str().unwrap(),
        "--scan",
        s_path.to_str().unwrap(),
        "--landmarks",
        l_path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let got = read_obj_positions(&out).unwrap();
    assert_eq!(got.len(), template.vertex_count());
    let rms = (got
        .iter()
        .zip(&truth.positions)
        .map(|(a, b)| (a - motion * b).norm_squared())
        .sum::<f64>()
        / got.len() as f64)
        .sqrt();
    println!("registered vertex error RMS {rms:.3} mm");
    assert!(rms < 0.5, "{rms}");
    // A malformed landmark line is one clear error.
    std::fs::write(&l_path, "vertex,x,y,z\n3,1.0,nope,2\n").unwrap();
    let o = helmcap(&[
        "register",
        "--template",
        t_path.to_str().unwrap(),
        "--scan",
        s_path.to_str().unwrap(),
        "--landmarks",
        l_path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("landmarks.csv:2"), "{stderr}");
}
