// The analytic BRDFs of `runtime.moments_resolve = "pixel_analytic"` (biscale-gpu,
// shade/brdf.wgsl): `biscale_shading::synth::Brdf::eval` in f32, one function per kind, on the
// parameters the host uploads from that very `Brdf` (`shade/brdf.rs`), so no constant is
// written twice; the test `brdf_matches_the_cpu` holds each kind to a bound derived from f32
// and Vulkan's precisions. The constants BRDF_* (kinds) are generated from the Rust ones and
// prepended by the host.
//
// Where the f32 evaluation departs from the f64 formula to stay accurate: a conductor's
// `a^2 = (|n^2 - s^2| + re) / 2` is taken as `2 eta^2 k^2 / (|n^2 - s^2| - re)` when `re < 0`
// (the same value without the cancellation: for Mitsuba's default `eta = 0` it is exactly 0,
// as in f64, where the direct form leaves sqrt(eps)); `pow(x, 0)` is 1 and `pow(0, e)` 0, as
// the CPU's `powf` (WGSL leaves `pow(0, 0)` undefined).

// Mirror of the Rust `GpuBrdf` (80 bytes; checked by the layout test). What a, b, c and s
// hold depends on the kind (see `GpuBrdf::new`).
struct Brdf {
    // BRDF_NONE (the material is shaded from its tables) or one of the kinds below.
    kind: u32,
    // Rough plastic: first float of its coating's external transmittance table in `coating`.
    coating: u32,
    // Rough plastic: 1 for `nonlinear`.
    nonlinear: u32,
    pad: u32,
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
    s: vec4<f32>,
}

// One per material, in scene order.
@group(0) @binding(13) var<storage, read> brdfs: array<Brdf>;
// The rough plastics' external transmittance tables (COATING_NODES floats each), or a
// placeholder.
@group(0) @binding(14) var<storage, read> coating: array<f32>;

const BRDF_INV_PI: f32 = 0.318309886183790671538;
const BRDF_PI: f32 = 3.14159265358979323846;

// x^e as `f64::powf` takes it at the edges: x^0 = 1 (0^0 too), 0^e = 0 for e > 0.
fn pow_or_edge(x: f32, e: f32) -> f32 {
    if e == 0.0 {
        return 1.0;
    }
    if x <= 0.0 {
        return 0.0;
    }
    return pow(x, e);
}

fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    return x2 * x2 * x;
}

// `biscale_core::scene::btf::phong_brdf`: kd / pi + ks (n + 2) / (2 pi) cos^n(alpha), alpha
// the angle between the view and the light mirrored about the normal.
fn phong(b: Brdf, l: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    let cos_alpha = max(dot(vec3<f32>(-l.x, -l.y, l.z), v), 0.0);
    let lobe = (b.s.x + 2.0) / (2.0 * BRDF_PI) * pow_or_edge(cos_alpha, b.s.x);
    return b.a.xyz * BRDF_INV_PI + b.b.xyz * lobe;
}

// Ashikhmin-Shirley 2000, equations 4 and 5 (rd = a, rs = b, nu = s.x, nv = s.y).
fn ashikhmin_shirley(b: Brdf, k1: vec3<f32>, k2: vec3<f32>) -> vec3<f32> {
    let n1 = max(k1.z, 0.0);
    let n2 = max(k2.z, 0.0);
    let sum = k1 + k2;
    var h = vec3<f32>(0.0, 0.0, 1.0);
    if dot(sum, sum) > 0.0 {
        h = normalize(sum);
    }
    let kh = max(dot(k1, h), 1e-12);
    let nh = max(h.z, 0.0);
    let sin2 = h.x * h.x + h.y * h.y;
    var e = 0.0;
    if sin2 > 0.0 {
        e = (b.s.x * h.x * h.x + b.s.y * h.y * h.y) / sin2;
    }
    let lobe = sqrt((b.s.x + 1.0) * (b.s.y + 1.0)) / (8.0 * BRDF_PI) * pow_or_edge(nh, e) / (kh * max(max(n1, n2), 1e-12));
    let schlick = pow5(1.0 - kh);
    let coupling = 28.0 / (23.0 * BRDF_PI) * (1.0 - pow5(1.0 - n1 / 2.0)) * (1.0 - pow5(1.0 - n2 / 2.0));
    let rs = b.b.xyz;
    return lobe * (rs + (1.0 - rs) * schlick) + b.a.xyz * (1.0 - rs) * coupling;
}

// GGX D(m) (`biscale_shading::microfacet::Ggx::d`), alpha already clamped, with Mitsuba's
// cut-off of tiny values.
fn ggx_d(alpha: f32, m: vec3<f32>) -> f32 {
    let a2 = alpha * alpha;
    let s = (m.x * m.x + m.y * m.y) / a2 + m.z * m.z;
    let d = 1.0 / (BRDF_PI * a2 * s * s);
    if d * m.z > 1e-20 {
        return d;
    }
    return 0.0;
}

// Smith's G1(v, m) for GGX.
fn smith_g1(alpha: f32, v: vec3<f32>, m: vec3<f32>) -> f32 {
    if dot(v, m) * v.z <= 0.0 {
        return 0.0;
    }
    let xy = alpha * alpha * (v.x * v.x + v.y * v.y);
    if xy == 0.0 {
        return 1.0;
    }
    let tan2 = xy / (v.z * v.z);
    return 2.0 / (1.0 + sqrt(1.0 + tan2));
}

// D(h) G(view, light, h) / (4 cos_v cos_l), the specular factor both microfacet BRDFs share.
fn microfacet(alpha: f32, l: vec3<f32>, v: vec3<f32>, h: vec3<f32>) -> f32 {
    let a = max(alpha, 1e-4);
    let d = ggx_d(a, h);
    if d == 0.0 {
        return 0.0;
    }
    return d * smith_g1(a, v, h) * smith_g1(a, l, h) / (4.0 * v.z * l.z);
}

// `biscale_shading::microfacet::fresnel_conductor` per channel (see the file's top for a^2).
fn fresnel_conductor(cos_i: f32, eta: vec3<f32>, k: vec3<f32>) -> vec3<f32> {
    let c2 = cos_i * cos_i;
    let s2 = 1.0 - c2;
    let re = eta * eta - k * k - s2;
    let ek = eta * eta * k * k;
    let ab2 = sqrt(max(re * re + 4.0 * ek, vec3<f32>(0.0)));
    let a2 = select(0.5 * (ab2 + re), 2.0 * ek / (ab2 - re), re < vec3<f32>(0.0));
    let a = sqrt(max(a2, vec3<f32>(0.0)));
    let rs = (ab2 + c2 - 2.0 * a * cos_i) / (ab2 + c2 + 2.0 * a * cos_i);
    let p = ab2 * c2 + s2 * s2;
    let q = 2.0 * a * cos_i * s2;
    let rp = rs * (p - q) / (p + q);
    return 0.5 * (rs + rp);
}

// Unpolarized reflectance of a dielectric of relative IOR eta seen from outside (cos_i >= 0),
// `biscale_shading::microfacet::fresnel_dielectric(..).reflectance`.
fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    if eta == 1.0 {
        return 0.0;
    }
    if cos_i == 0.0 {
        return 1.0;
    }
    let eta_ti = 1.0 / eta;
    let ct = sqrt(max(1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti, 0.0));
    let a_s = (cos_i - eta * ct) / (cos_i + eta * ct);
    let a_p = (ct - eta * cos_i) / (ct + eta * cos_i);
    return 0.5 * (a_s * a_s + a_p * a_p);
}

// Rough conductor: eta = a, k = b, specular_reflectance = c, alpha = s.x.
fn rough_conductor(b: Brdf, l: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    let h = normalize(l + v);
    return b.c.xyz * fresnel_conductor(dot(v, h), b.a.xyz, b.b.xyz) * microfacet(b.s.x, l, v, h);
}

// The coating's external transmittance at cosine mu, linear between its COATING_NODES nodes
// (`CoatingTable::transmittance`).
fn transmittance(at: u32, mu: f32) -> f32 {
    let x = mu * f32(COATING_NODES - 1u);
    let j = min(u32(max(x, 0.0)), COATING_NODES - 2u);
    let w = x - f32(j);
    return (1.0 - w) * coating[at + j] + w * coating[at + j + 1u];
}

// Rough plastic: diffuse_reflectance = a, specular_reflectance = b, alpha = s.x, eta =
// int_ior / ext_ior = s.y, internal reflectance R_int = s.z.
fn rough_plastic(b: Brdf, l: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    let eta = b.s.y;
    let h = normalize(l + v);
    let spec = fresnel_dielectric(dot(v, h), eta) * microfacet(b.s.x, l, v, h);
    let scale = transmittance(b.coating, v.z) * transmittance(b.coating, l.z) / (BRDF_PI * eta * eta);
    let rho = b.a.xyz;
    let r_int = select(vec3<f32>(b.s.z), rho * b.s.z, b.nonlinear != 0u);
    return rho / (1.0 - r_int) * scale + b.b.xyz * spec;
}

// f(light, view) of `b` for local unit directions (+Z the shading normal); 0 when either is
// at or below the horizon, as `Brdf::eval`.
fn brdf_eval(b: Brdf, l: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    if !(l.z > 0.0 && v.z > 0.0) {
        return vec3<f32>(0.0);
    }
    switch b.kind {
        case BRDF_LAMBERTIAN: {
            return b.a.xyz * BRDF_INV_PI;
        }
        case BRDF_PHONG: {
            return phong(b, l, v);
        }
        case BRDF_ASHIKHMIN_SHIRLEY: {
            return ashikhmin_shirley(b, l, v);
        }
        case BRDF_ROUGH_CONDUCTOR: {
            return rough_conductor(b, l, v);
        }
        case BRDF_ROUGH_PLASTIC: {
            return rough_plastic(b, l, v);
        }
        default: {
            return vec3<f32>(0.0);
        }
    }
}
