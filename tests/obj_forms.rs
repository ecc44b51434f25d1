//! The OBJ statement forms other tools write (issue 18) load with the right counts.

use std::path::Path;

use helmcap::mesh::read_obj;

/// (file, vertices, faces, corners, UVs) of each corpus file.
const CORPUS: &[(&str, usize, usize, usize, usize)] = &[
    ("empty_fields.obj", 5, 3, 9, 0),
    ("trailing_slash_uv.obj", 4, 2, 6, 4),
    ("continuation.obj", 4, 1, 4, 0),
    ("nan_colour.obj", 4, 1, 4, 0),
    // Four UVs of the file plus the shared (0, 0) of the untextured face.
    ("mixed_uv.obj", 5, 2, 7, 5),
];

#[test]
fn obj_forms_load_with_the_right_counts() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/obj_forms");
    for &(file, vertices, faces, corners, uvs) in CORPUS {
        let m = read_obj(&dir.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(m.positions.len(), vertices, "{file}: vertices");
        assert_eq!(m.face_count(), faces, "{file}: faces");
        let n: usize = (0..m.face_count()).map(|f| m.face(f).len()).sum();
        assert_eq!(n, corners, "{file}: corners");
        assert_eq!(m.uvs.len(), uvs, "{file}: UVs");
        if uvs > 0 {
            for f in 0..m.face_count() {
                assert_eq!(m.face_uv(f).len(), m.face(f).len(), "{file}: face {f} UVs");
            }
        }
    }
}
