//! Tests of the pictures: every pixel where the module docs say, against independent
//! formulas.

use super::heatmap::*;
use super::histograms::*;
use super::patch::*;
use super::raster::*;
use biscale_compressors::bicluster::{Bicluster, BiclusterView};
use biscale_compressors::testing::{self, random_transfer};
use biscale_core::basis::TransferShape;
use biscale_core::compress::CompressedForm;
use biscale_core::compress::{ArrayData, CompressContext, Compressor};
use biscale_core::geometry::shapes;
use biscale_core::geometry::Mesh;
use biscale_core::scene::Camera;
use biscale_core::transfer::TransferMatrix;
use biscale_shading::image::{viridis, NON_FINITE_COLOUR};
use glam::Vec3;
use std::collections::BTreeMap;
use std::path::Path;

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

fn open(p: &Path) -> image::RgbImage {
    image::open(p).unwrap().into_rgb8()
}

/// `T` from explicit `(row, col, value)` entries: `vertices` of `m = g^2` rows each over
/// the R x R cubemap.
fn matrix(vertices: usize, m: usize, r: u32, entries: &[(usize, usize, f32)]) -> TransferMatrix {
    let light = testing::cubemap(r);
    let g = (1..=64).find(|g| g * g == m as u32).expect("m must be a square");
    let mut tri = sprs::TriMat::new((vertices * m, light.len()));
    for &(i, k, v) in entries {
        tri.add_triplet(i, k, v);
    }
    TransferMatrix::new(testing::bins(g), light, tri.to_csr()).unwrap()
}

fn value(t: &TransferMatrix, i: usize, k: usize) -> f32 {
    t.csr().get(i, k).copied().unwrap_or(0.0)
}

/// Expected top-left pixel of entry (patch row il, column k) in the uncompacted matrix
/// layout, from the module docs' formula (written out independently of `Grid`).
fn matrix_origin(t: &TransferMatrix, cell: u32, il: usize, k: usize) -> (u32, u32) {
    let r2 = (t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution
        * t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution) as usize;
    let faces_left = (k / r2) as u32;
    (LEFT + k as u32 * cell + faces_left * LINE, HEADER + il as u32 * cell + (il / t.local_dirs()) as u32 * LINE)
}

fn panel_origin(t: &TransferMatrix, cell: u32, p: usize, k: usize) -> (u32, u32) {
    let r = t.light_basis().cubemap_layout().expect("a cubemap light basis").resolution as usize;
    let (face, row, col) = (k / (r * r), (k / r) % r, k % r);
    let side = r as u32 * cell;
    (LEFT + face as u32 * (side + GAP) + col as u32 * cell, HEADER + p as u32 * (side + GAP) + row as u32 * cell)
}

#[test]
fn sparsity_matrix_shows_every_entry_of_a_random_t_where_it_belongs() {
    let t = random_transfer(5, 2, 4, 0.15, 7);
    let dir = tmp();
    let view = PatchView { first_vertex: 1, vertices: 3, layout: PatchLayout::Matrix { compact: false }, cell: 3 };
    let path = write_sparsity(&t, &view, &dir.path().join("s.png")).unwrap();
    let img = open(&path);
    // 96 columns, 6 faces: 5 boundary lines; 12 rows, 2 vertex separators.
    let w = (LEFT + 96 * 3 + 5 * LINE + RIGHT).max(MIN_WIDTH);
    assert_eq!(img.dimensions(), (w, HEADER + 12 * 3 + 2 * LINE + FOOTER));
    let mut nonzeros = 0;
    for il in 0..12 {
        for k in 0..96 {
            let v = value(&t, 4 + il, k);
            let (x, y) = matrix_origin(&t, 3, il, k);
            // Every pixel of the cell, not only its centre.
            for (dx, dy) in [(0, 0), (1, 1), (2, 2), (2, 0)] {
                let got = img.get_pixel(x + dx, y + dy).0;
                if v == 0.0 {
                    assert_eq!(got, WHITE_PX, "zero T[{}, {k}] is white", 4 + il);
                } else {
                    // 255 (1 - v): 1/4 -> 191, 1/2 -> 128, 3/4 -> 64, 1 -> 0.
                    assert_eq!(
                        got,
                        [[191u8; 3], [128; 3], [64; 3], [0; 3]][(v * 4.0) as usize - 1],
                        "T[{}, {k}] = {v}",
                        4 + il
                    );
                }
            }
            nonzeros += (v != 0.0) as usize;
        }
    }
    assert!(nonzeros > 100, "the random T has entries to check ({nonzeros})");
    // Face boundaries are accent lines between the faces, spanning the content.
    let (x, y) = matrix_origin(&t, 3, 0, 16);
    assert_eq!(img.get_pixel(x - 1, y).0, ACCENT);
}

#[test]
fn compact_matrix_keeps_only_touched_columns_in_order() {
    // Vertex 0 (outside the patch) touches column 3, the patch columns 5 and 30 (faces 1, 7).
    // Vertex 1's rows are 4..8 (M = 4); its first two rows hold the entries.
    let t = matrix(2, 4, 2, &[(0, 3, 1.0), (4, 5, 0.5), (5, 20, 0.25)]);
    let dir = tmp();
    let view = PatchView { first_vertex: 1, vertices: 1, layout: PatchLayout::Matrix { compact: true }, cell: 5 };
    let img = open(&write_sparsity(&t, &view, &dir.path().join("c.png")).unwrap());
    assert_eq!(img.dimensions(), (MIN_WIDTH, HEADER + 4 * 5 + FOOTER));
    // Column 5 (face 1) first, column 20 (face 5) second after one boundary line.
    assert_eq!(img.get_pixel(LEFT + 2, HEADER + 2).0, [128; 3]);
    assert_eq!(img.get_pixel(LEFT + 5 + LINE + 2, HEADER + 5 + 2).0, [191; 3]);
    assert_eq!(img.get_pixel(LEFT + 5 + LINE + 2, HEADER + 2).0, WHITE_PX, "T[4, 20] = 0");
    assert_eq!(img.get_pixel(LEFT + 5 + LINE + 5 + 2, HEADER + 2).0, WHITE_PX, "nothing right of the last column");
}

#[test]
fn sparsity_panels_fold_a_vertex_onto_the_cubemap() {
    // Like a real T: at each vertex every texel belongs to one bin j (here k mod M).
    let (r, m) = (4u32, 4usize);
    let mut entries = vec![];
    for p in 0..3 {
        for k in 0..96usize {
            if (k * 7 + p) % 3 != 0 {
                entries.push((p * m + k % m, k, ((k + p) % 4 + 1) as f32 / 4.0));
            }
        }
    }
    let t = matrix(3, m, r, &entries);
    let dir = tmp();
    let view = PatchView { first_vertex: 1, vertices: 2, layout: PatchLayout::CubemapPanels, cell: 4 };
    let img = open(&write_sparsity(&t, &view, &dir.path().join("p.png")).unwrap());
    let side = 4 * 4;
    let w = (LEFT + 6 * side + 5 * GAP + RIGHT).max(MIN_WIDTH);
    assert_eq!(img.dimensions(), (w, HEADER + 2 * side + GAP + FOOTER));
    for p in 0..2 {
        for k in 0..96 {
            let v = value(&t, (1 + p) * m + k % m, k);
            let (x, y) = panel_origin(&t, 4, p, k);
            let want = if v == 0.0 { WHITE_PX } else { value_grey(v) };
            assert_eq!(img.get_pixel(x + 1, y + 1).0, want, "vertex {} texel {k}", 1 + p);
            // Right neighbour non-zero in another bin (k + 1 mod M differs): blue edge.
            let r = r as usize;
            if v != 0.0 && k % r + 1 < r && value(&t, (1 + p) * m + (k + 1) % m, k + 1) != 0.0 {
                assert_eq!(img.get_pixel(x + 3, y + 1).0, ACCENT, "bin boundary right of texel {k}");
            }
        }
    }
}

/// A bicluster form written out by hand (global row ids, one block).
fn hand_form(rows: usize, cols: usize, m: usize, q: u32, bcs: &[(Vec<u32>, Vec<u16>, Vec<i8>)]) -> CompressedForm {
    let mut bc_col_ptr = vec![0u32];
    let (mut bc_cols, mut bc_vals) = (vec![], vec![]);
    let mut per_row: Vec<Vec<u32>> = vec![vec![]; rows];
    for (b, (rs, ks, vs)) in bcs.iter().enumerate() {
        bc_cols.extend_from_slice(ks);
        bc_vals.extend_from_slice(vs);
        bc_col_ptr.push(bc_cols.len() as u32);
        for &i in rs {
            per_row[i as usize].push(b as u32);
        }
    }
    let mut row_ptr = vec![0u32];
    let mut row_bc = vec![];
    for l in &per_row {
        row_bc.extend_from_slice(l);
        row_ptr.push(row_bc.len() as u32);
    }
    let g = (1..=64).find(|g| (g * g) as usize == m).expect("m must be a square");
    let r = (1..=104).find(|r| (6 * r * r) as usize == cols).expect("cols must be 6 R^2");
    let shape = TransferShape::from_rows(rows, testing::bins(g), testing::cubemap(r)).unwrap();
    let mut form = CompressedForm::new("bicluster", shape)
        .with_array("bc_col_ptr", ArrayData::U32(bc_col_ptr))
        .with_array("bc_cols", ArrayData::U16(bc_cols))
        .with_array("bc_vals", ArrayData::I8(bc_vals))
        .with_array("row_ptr", ArrayData::U32(row_ptr))
        .with_array("row_bc", ArrayData::U32(row_bc))
        .with_array("block_bc_base", ArrayData::U32(vec![0, bcs.len() as u32]));
    form.meta = BTreeMap::from([
        ("value_scale".into(), q as u64),
        ("block_rows".into(), rows as u64),
        ("blocks".into(), 1),
        ("biclusters".into(), bcs.len() as u64),
        ("row_bc_local".into(), 0),
    ]);
    form.lossless = true;
    form
}

#[test]
fn bicluster_patch_of_a_random_t_colours_every_entry_by_a_covering_bicluster() {
    let t = random_transfer(6, 2, 4, 0.2, 3);
    let form = Bicluster { block_vertices: 3, value_scale: 0, ..Bicluster::default() }
        .compress(&t, &CompressContext::default())
        .unwrap();
    let bv = BiclusterView::new(&form).unwrap();
    let dir = tmp();
    let cell = 5;
    let view = PatchView { first_vertex: 2, vertices: 3, layout: PatchLayout::Matrix { compact: false }, cell };
    let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("b.png")).unwrap());
    let w = (LEFT + 96 * cell + 5 * LINE + RIGHT).max(MIN_WIDTH);
    assert_eq!(img.dimensions(), (w, HEADER + 12 * cell + 2 * LINE + FOOTER));
    let (mut checked, mut overlaps) = (0, 0);
    for il in 0..12 {
        let i = 8 + il;
        let ids: Vec<usize> = bv.row_biclusters(i).collect();
        for k in 0..96 {
            // Brute force: every bicluster of the row whose columns contain k.
            let cover: Vec<usize> = ids.iter().copied().filter(|&b| bv.bicluster(b).0.contains(&(k as u16))).collect();
            let (x, y) = matrix_origin(&t, cell, il, k);
            let corner = img.get_pixel(x, y).0;
            let centre = img.get_pixel(x + cell / 2, y + cell / 2).0;
            let v = value(&t, i, k);
            if cover.is_empty() {
                assert_eq!(v, 0.0, "lossless form: a non-zero is covered");
                assert_eq!((corner, centre), (WHITE_PX, WHITE_PX));
                continue;
            }
            let first = *cover.iter().min().unwrap();
            let want = if v == 0.0 { mix(bicluster_colour(first), WHITE_PX, 0.65) } else { bicluster_colour(first) };
            assert_eq!(corner, want, "T[{i}, {k}] covered by {cover:?}");
            assert_eq!(centre, if cover.len() > 1 { BLACK_PX } else { want }, "overlap mark at T[{i}, {k}]");
            checked += 1;
            overlaps += (cover.len() > 1) as usize;
        }
    }
    assert!(checked > 50, "{checked} covered entries checked");
    eprintln!("{checked} covered entries, {overlaps} overlaps");
}

#[test]
fn a_single_bicluster_is_one_colour() {
    // Rows 0..8 (vertices 0 and 1, M = 4), columns 3, 10, 40 with constants 1/4, 1, 3/4:
    // one constant-column bicluster covers all of T.
    let mut entries = vec![];
    for i in 0..8 {
        for (k, v) in [(3, 0.25), (10, 1.0), (40, 0.75)] {
            entries.push((i, k, v));
        }
    }
    let t = matrix(2, 4, 4, &entries);
    let form = Bicluster::global().compress(&t, &CompressContext::default()).unwrap();
    assert_eq!(BiclusterView::new(&form).unwrap().biclusters(), 1, "greedy finds the one bicluster");
    let dir = tmp();
    for layout in [PatchLayout::Matrix { compact: false }, PatchLayout::CubemapPanels] {
        let view = PatchView { first_vertex: 0, vertices: 2, layout, cell: 4 };
        let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("one.png")).unwrap());
        for p in 0..2 {
            for j in 0..4 {
                for k in 0..96 {
                    let (x, y) = match layout {
                        PatchLayout::CubemapPanels => panel_origin(&t, 4, p, k),
                        _ => matrix_origin(&t, 4, p * 4 + j, k),
                    };
                    let want = if [3, 10, 40].contains(&k) { bicluster_colour(0) } else { WHITE_PX };
                    assert_eq!(img.get_pixel(x + 1, y + 2).0, want, "{layout:?} row {} col {k}", p * 4 + j);
                }
            }
        }
    }
}

#[test]
fn overlaps_and_cancellations_are_marked_and_a_foreign_form_is_refused() {
    // q = 4. One vertex of M = 4 rows. T row 0: (k0 1/2, k1 1/4); row 1: (k0 1/2, k1 0);
    // rows 2 and 3 empty. B0 = rows {0, 1} x cols {0, 1} with codes (2, 1); B1 = row {1}
    // x col {1}, code -1.
    let t = matrix(1, 4, 4, &[(0, 0, 0.5), (0, 1, 0.25), (1, 0, 0.5)]);
    let form = hand_form(4, 96, 4, 4, &[(vec![0, 1], vec![0, 1], vec![2, 1]), (vec![1], vec![1], vec![-1])]);
    let dir = tmp();
    let cell = 6;
    let view = PatchView { first_vertex: 0, vertices: 1, layout: PatchLayout::Matrix { compact: true }, cell };
    let img = open(&write_bicluster_patch(&t, &form, &view, &dir.path().join("o.png")).unwrap());
    let px = |i: u32, c: u32, dx: u32, dy: u32| img.get_pixel(LEFT + c * cell + dx, HEADER + i * cell + dy).0;
    let (c0, pale) = (bicluster_colour(0), mix(bicluster_colour(0), WHITE_PX, 0.65));
    assert_eq!((px(0, 0, 0, 0), px(0, 0, 3, 3)), (c0, c0), "B0 alone");
    assert_eq!((px(0, 1, 0, 0), px(0, 1, 3, 3)), (c0, c0));
    assert_eq!((px(1, 0, 0, 0), px(1, 0, 3, 3)), (c0, c0));
    // dot = cell / 3 = 2 pixels at offset (cell - 2) / 2 = 2.
    assert_eq!((px(1, 1, 0, 0), px(1, 1, 2, 2), px(1, 1, 3, 3)), (pale, BLACK_PX, BLACK_PX), "cancelled overlap");
    // The same form against a T that it does not sum to.
    let other = matrix(1, 4, 4, &[(0, 0, 0.5), (0, 1, 0.25), (1, 0, 0.75)]);
    let e = write_bicluster_patch(&other, &form, &view, &dir.path().join("x.png")).unwrap_err().to_string();
    assert!(e.contains("T[1, 0]"), "{e}");
    assert!(!dir.path().join("x.png").exists());
    // Shape mismatch and patch outside T.
    let wide = matrix(2, 4, 4, &[]);
    assert!(write_bicluster_patch(&wide, &form, &view, &dir.path().join("y.png")).is_err());
    let far = PatchView { first_vertex: 1, ..view };
    assert!(write_bicluster_patch(&t, &form, &far, &dir.path().join("y.png")).is_err());
    assert!(write_sparsity(&t, &far, &dir.path().join("y.png")).is_err());
    assert!(write_sparsity(&t, &PatchView { cell: 0, ..view }, &dir.path().join("y.png")).is_err());
    assert!(!dir.path().join("y.png").exists());
}

#[test]
fn histograms_have_the_documented_size_and_their_bars() {
    let t = random_transfer(8, 2, 4, 0.2, 5);
    let form = Bicluster::default().compress(&t, &CompressContext::default()).unwrap();
    let dir = tmp();
    let count = |img: &image::RgbImage, c: [u8; 3], left: bool| {
        img.enumerate_pixels().filter(|(x, _, p)| (*x < img.width() / 2) == left && p.0 == c).count()
    };
    let img = open(&write_bicluster_size_histograms(&form, &dir.path().join("h.png")).unwrap());
    assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
    assert!(count(&img, [70, 130, 220], true) > 200, "r bars on the left");
    assert!(count(&img, [230, 140, 40], false) > 200, "l bars on the right");
    let img = open(&write_value_histograms(&t, Some(&form), &dir.path().join("v.png")).unwrap());
    assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
    assert!(count(&img, [110, 110, 110], true) > 200, "T value bars");
    let bv = BiclusterView::new(&form).unwrap();
    let negative = bv.bc_vals.iter().any(|&c| c < 0);
    assert_eq!(count(&img, [230, 120, 30], false) > 0, negative, "orange bars iff residual codes < 0");
    let img = open(&write_value_histograms(&t, None, &dir.path().join("v.png")).unwrap());
    assert_eq!(img.dimensions(), HISTOGRAM_SIZE);
    // One distinct value: a single bar; no values at all: a note instead of a chart.
    let one = matrix(1, 1, 1, &[(0, 0, 1.0), (0, 4, 1.0)]);
    let img = open(&write_value_histograms(&one, None, &dir.path().join("1.png")).unwrap());
    assert!(count(&img, [110, 110, 110], true) > 200);
    let none = matrix(1, 1, 1, &[]);
    let img = open(&write_value_histograms(&none, None, &dir.path().join("0.png")).unwrap());
    assert_eq!(count(&img, [110, 110, 110], true), 0);
}

#[test]
fn non_zeros_per_vertex_add_up() {
    let t = random_transfer(10, 2, 4, 0.1, 9);
    let nnz = nnz_per_vertex(&t);
    for (v, &n) in nnz.iter().enumerate() {
        let direct = (0..4).map(|j| t.csr().outer_view(v * 4 + j).unwrap().nnz()).sum::<usize>();
        assert_eq!(n as usize, direct);
    }
    assert_eq!(nnz.iter().sum::<f32>() as usize, t.nnz());
}

fn top_camera(mesh: &Mesh) -> Camera {
    let (lo, hi) = mesh.bounds();
    Camera::frame_bounds(lo, hi, 80, 60, 0.0, 90.0, 40.0)
}

#[test]
fn heatmap_of_a_constant_is_one_colour() {
    let mesh = shapes::grid_plane(6, 2.0);
    let cam = top_camera(&mesh);
    let dir = tmp();
    let opts = HeatmapOptions { range: None, relief: 0.0 };
    let img = open(
        &write_vertex_heatmap(&mesh, &cam, &vec![3.5; mesh.vertex_count()], "const", &opts, &dir.path().join("c.png"))
            .unwrap(),
    );
    assert_eq!(img.dimensions(), heatmap_size(&cam));
    let mut covered = 0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            let p = img.get_pixel(x, y + TITLE_HEIGHT).0;
            if p != WHITE_PX {
                assert_eq!(p, viridis(0.5), "pixel ({x}, {y})");
                covered += 1;
            }
        }
    }
    // The plane seen from above fills a square of about 0.55 of the height: >= 1/4 of it.
    assert!(covered > (cam.width * cam.height / 4) as usize, "{covered}");
    // Bad inputs are errors.
    assert!(write_vertex_heatmap(&mesh, &cam, &[1.0], "x", &opts, &dir.path().join("e.png")).is_err());
    let bad = HeatmapOptions { range: Some((1.0, 0.0)), relief: 0.0 };
    assert!(write_vertex_heatmap(&mesh, &cam, &vec![0.0; mesh.vertex_count()], "x", &bad, &dir.path().join("e.png"))
        .is_err());
}

#[test]
fn heatmap_of_a_ramp_matches_the_ramp_at_every_pixel() {
    let mesh = shapes::grid_plane(6, 2.0);
    let cam = top_camera(&mesh);
    // s = x, in [-1, 1]; linear, so barycentric interpolation reproduces it exactly.
    let values: Vec<f32> = mesh.positions.iter().map(|p| p.x).collect();
    let dir = tmp();
    let opts = HeatmapOptions { range: None, relief: 0.0 };
    let img = open(&write_vertex_heatmap(&mesh, &cam, &values, "x", &opts, &dir.path().join("r.png")).unwrap());
    let lum = |c: [u8; 3]| 0.2126 * c[0] as f32 + 0.7152 * c[1] as f32 + 0.0722 * c[2] as f32;
    let mut checked = 0;
    for y in 0..cam.height {
        let mut prev: Option<f32> = None;
        for x in 0..cam.width {
            let p = img.get_pixel(x, y + TITLE_HEIGHT).0;
            // Independent: intersect the pixel's ray with the plane y = 0.
            let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = o + d * (-o.y / d.y);
            if hit.x.abs() > 0.999 || hit.z.abs() > 0.999 {
                continue; // at the plane's edge a ray may just miss
            }
            let want = viridis((hit.x + 1.0) / 2.0);
            // f32 ray/barycentric rounding moves t by ~1e-6; viridis channels then move by
            // at most 1 unit after rounding to 8 bits.
            assert!(p.iter().zip(&want).all(|(a, b)| a.abs_diff(*b) <= 1), "({x}, {y}): {p:?} vs {want:?}");
            if let Some(l) = prev {
                assert!(lum(p) >= l - 0.75, "luminance increases along +x at ({x}, {y})");
            }
            prev = Some(lum(p));
            checked += 1;
        }
    }
    assert!(checked > 1000, "{checked}");
    // Image x grows along world +X for this camera: left is dark, right is bright.
    let row = cam.height / 2 + TITLE_HEIGHT;
    let covered: Vec<u32> = (0..cam.width).filter(|&x| img.get_pixel(x, row).0 != WHITE_PX).collect();
    let (a, b) = (img.get_pixel(covered[0], row).0, img.get_pixel(*covered.last().unwrap(), row).0);
    assert!(lum(b) > lum(a) + 100.0, "{a:?} -> {b:?}");
    // Colour bar: top is viridis(1), bottom viridis(0).
    let bx = cam.width + 18 + 10;
    assert_eq!(img.get_pixel(bx, TITLE_HEIGHT + 14).0, viridis(1.0));
    assert_eq!(img.get_pixel(bx, img.height() - 15).0, viridis(0.0));
    // A NaN vertex shows as magenta where it weighs in.
    let mut nan = values.clone();
    nan[mesh.positions.iter().position(|p| *p == Vec3::ZERO).unwrap()] = f32::NAN;
    let img = open(&write_vertex_heatmap(&mesh, &cam, &nan, "x", &opts, &dir.path().join("n.png")).unwrap());
    assert_eq!(img.get_pixel(cam.width / 2, cam.height / 2 + TITLE_HEIGHT).0, NON_FINITE_COLOUR);
}
