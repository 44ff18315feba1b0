//! Every struct shared between Rust and WGSL has the same size and member offsets on both
//! sides (`GatherParams` is checked in biscale-kernels, beside the prelude): naga's WGSL front end lays the WGSL struct out (the same layout wgpu uses) and we
//! compare with `offset_of!` on the `#[repr(C)]` Rust struct. A vec3 followed by a scalar, or
//! a missing pad, shows up here instead of as garbage on the GPU.

use crate::present::present_wgsl;
use crate::shade::shade_wgsl;
use crate::{GpuMaterialHeader, GpuVertex, ShadeParams};
use std::mem::{offset_of, size_of};

/// (WGSL struct name, Rust size, [(WGSL member, Rust offset)]) checked against `source`.
fn check(source: &str, name: &str, size: usize, members: &[(&str, usize)]) {
    let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    let ty = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("WGSL has no struct {name}"))
        .1;
    let naga::TypeInner::Struct { members: wgsl, span } = &ty.inner else { panic!("{name} is not a struct") };
    assert_eq!(*span as usize, size, "{name}: WGSL size {span} vs Rust size {size}");
    assert_eq!(wgsl.len(), members.len(), "{name}: WGSL has {} members, the table {}", wgsl.len(), members.len());
    for (w, (rust_name, rust_offset)) in wgsl.iter().zip(members) {
        assert_eq!(w.name.as_deref(), Some(*rust_name), "{name}: member order differs");
        assert_eq!(
            w.offset as usize, *rust_offset,
            "{name}.{rust_name}: WGSL offset {} vs Rust {rust_offset}",
            w.offset
        );
    }
}

#[test]
fn shade_params_layout_matches_wgsl() {
    type P = ShadeParams;
    let members = [
        ("view_proj", offset_of!(P, view_proj)),
        ("cam_right", offset_of!(P, cam_right)),
        ("width", offset_of!(P, width)),
        ("cam_up", offset_of!(P, cam_up)),
        ("height", offset_of!(P, height)),
        ("cam_forward", offset_of!(P, cam_forward)),
        ("local_dirs", offset_of!(P, local_dirs)),
        ("camera_pos", offset_of!(P, camera_pos)),
        ("pad_camera", offset_of!(P, _pad0)),
        ("material_count", offset_of!(P, material_count)),
        ("has_material_ids", offset_of!(P, has_material_ids)),
        ("vertex_count", offset_of!(P, vertex_count)),
        ("triangle_count", offset_of!(P, triangle_count)),
        ("max_components", offset_of!(P, max_components)),
        ("resolve", offset_of!(P, resolve)),
        ("moment_grid", offset_of!(P, moment_grid)),
        ("lobe", offset_of!(P, lobe)),
    ];
    // The shading passes and the tone-mapping pass (camera rays for the background) both
    // bind the same uniform buffer.
    check(&shade_wgsl(), "ShadeParams", size_of::<P>(), &members);
    check(&present_wgsl(), "ShadeParams", size_of::<P>(), &members);
}

#[test]
fn material_header_layout_matches_wgsl() {
    type H = GpuMaterialHeader;
    check(
        &shade_wgsl(),
        "MaterialHeader",
        size_of::<H>(),
        &[
            ("data_offset", offset_of!(H, data_offset)),
            ("width", offset_of!(H, width)),
            ("height", offset_of!(H, height)),
            ("view_m", offset_of!(H, view_m)),
            ("tiling", offset_of!(H, tiling)),
            ("kind", offset_of!(H, kind)),
            ("clusters", offset_of!(H, clusters)),
            ("components", offset_of!(H, components)),
            ("per_view", offset_of!(H, per_view)),
            ("weights_offset", offset_of!(H, weights_offset)),
            ("ids_offset", offset_of!(H, ids_offset)),
            ("pad0", offset_of!(H, _pad)),
        ],
    );
}

#[test]
fn vertex_layout_matches_wgsl() {
    type V = GpuVertex;
    check(
        &shade_wgsl(),
        "Vertex",
        size_of::<V>(),
        &[
            ("position", offset_of!(V, position)),
            ("u", offset_of!(V, u)),
            ("normal", offset_of!(V, normal)),
            ("v", offset_of!(V, v)),
            ("tangent", offset_of!(V, tangent)),
            ("pad", offset_of!(V, _pad)),
        ],
    );
}

#[test]
fn brdf_layout_matches_wgsl() {
    type B = crate::shade::GpuBrdf;
    check(
        &shade_wgsl(),
        "Brdf",
        size_of::<B>(),
        &[
            ("kind", offset_of!(B, kind)),
            ("coating", offset_of!(B, coating)),
            ("nonlinear", offset_of!(B, nonlinear)),
            ("pad", offset_of!(B, _pad)),
            ("a", offset_of!(B, a)),
            ("b", offset_of!(B, b)),
            ("c", offset_of!(B, c)),
            ("s", offset_of!(B, s)),
        ],
    );
}

#[test]
fn resolve_params_layout_matches_wgsl() {
    type P = crate::moments::ResolveParams;
    check(
        &crate::moments::resolve_wgsl(),
        "ResolveParams",
        size_of::<P>(),
        &[
            ("vertices", offset_of!(P, vertices)),
            ("grid", offset_of!(P, grid)),
            ("lobe", offset_of!(P, lobe)),
            ("groups_x", offset_of!(P, groups_x)),
        ],
    );
}

#[test]
fn layout_check_catches_a_vec3_followed_by_a_misplaced_scalar() {
    // The check itself must fail on the classic mistake: Rust packs [f32; 3] + u32 into 16
    // bytes, WGSL puts a vec3<f32> at a 16-byte boundary.
    let wgsl = "struct Bad { a: f32, b: vec3<f32>, c: u32 }";
    let r = std::panic::catch_unwind(|| check(wgsl, "Bad", 20, &[("a", 0), ("b", 4), ("c", 16)]));
    assert!(r.is_err());
}
