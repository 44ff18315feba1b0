//! A scene's materials: the config's entries turned into BTFs and matched to the mesh.
//!
//! * Analytic entries (`lambertian`, `phong`) are tabulated directly (`Btf::lambertian`,
//!   `Btf::phong`). A `synthesized` entry is ray traced from its height-field patch
//!   (`biscale_shading::synth`), or loaded from the cache, keyed by a hash of everything that
//!   determines it (the entry, the files it names, the local basis and the format versions).
//!   Every BTF is tabulated on `T`'s local basis (the caller passes `t.local_basis()`), so
//!   the BTFs' light directions are the rows of `T` by construction.
//!   The table a run uses is always the one its encoding stores (it goes through
//!   `btf_artifact` / `btf_from_artifact` even without a cache), so a cached and a fresh run
//!   agree bit for bit.
//! * Matching: triangle `t` uses the entry whose `name` is the OBJ's material name of `t`
//!   (`Mesh::materials`). A single unnamed entry covers the whole mesh. An OBJ material no
//!   entry names is an error naming both files; an entry no triangle uses is left out (not
//!   built) and said so.
//! * Leaving out what a scene does not need: when only one material is used there are no
//!   per-triangle ids (and no id buffer on the GPU); the diffuse special case drops the view
//!   axis; a flat patch with an analytic BRDF is tabulated without ray tracing. Each such
//!   decision is a line in [`SceneMaterials::notes`], printed with the plan.

use crate::error::{PipelineError, Result};
use crate::experiment::config::{Experiment, MaterialConfig, RepresentationSetting, SynthesizedConfig};
use crate::store::cache::{CacheKey, StageCache};
use crate::util::progress_bar;
use biscale_core::artifact::Artifact;
use biscale_core::basis::LocalBasis;
use biscale_core::geometry::Mesh;
use biscale_core::io::ContentHash;
use biscale_core::scene::{Btf, LpcaBtf, LpcaQuantize, LpcaSettings, Material};
use biscale_shading::synth::{
    btf_artifact, btf_from_artifact, synthesize, AlbedoMap, Brdf, BtfEncoding, BtfSpec, HeightField, Pattern, Recipe,
};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Bump when the meaning of a synthesized BTF changes, so cached tables are not reused.
const SYNTH_VERSION: u32 = 1;

/// The materials a scene is shaded with.
pub struct SceneMaterials {
    /// The materials used, in the order of [`Self::labels`].
    pub materials: Vec<Material>,
    /// Index into `materials` per triangle; `None` when one material covers the mesh.
    pub triangle_materials: Option<Vec<u32>>,
    /// The config label (name or kind) of each material.
    pub labels: Vec<String>,
    /// What was left out or repaired, one line each (printed with the plan, kept in the report).
    pub notes: Vec<String>,
    /// Every representation of every material, with its storage and error: each material's own
    /// first, then the other settings its entry lists (`variants` says which is which).
    pub btfs: Vec<crate::metrics::BtfRecord>,
    /// One per record of `btfs`: its material and, for a setting other than the material's
    /// own, the representation.
    pub variants: Vec<BtfVariant>,
    /// The dense table of each material whose own representation is compressed (the BTF
    /// study's all-dense image needs it); `None` where the material is dense.
    pub dense: Vec<Option<Btf>>,
    /// The BRDF of each material that is one ([`analytic_brdf`]): the ground-truth reference
    /// evaluates it at each texel's exact direction instead of looking up the table.
    pub analytic: Vec<Option<Brdf>>,
}

/// The BRDF a material entry is, when its BTF is nothing but a tabulated BRDF: Lambertian,
/// Phong, and a flat synthesized patch (`amplitude = 0`) without an albedo map. A height-field
/// or measured BTF has only its table.
pub fn analytic_brdf(cfg: &MaterialConfig) -> Option<Brdf> {
    match cfg {
        MaterialConfig::Lambertian { albedo, .. } => Some(Brdf::Lambertian { albedo: *albedo }),
        MaterialConfig::Phong { kd, ks, exponent, .. } => Some(Brdf::Phong { kd: *kd, ks: *ks, exponent: *exponent }),
        MaterialConfig::Synthesized(s) if s.amplitude == 0.0 && s.albedo_map.is_none() => Some(s.brdf),
        MaterialConfig::Synthesized(_) | MaterialConfig::Bonn(_) => None,
    }
}

/// One representation of one material (a record of [`SceneMaterials::btfs`]).
pub struct BtfVariant {
    /// Index into [`SceneMaterials::materials`].
    pub material: usize,
    /// `None`: the material's own (in `materials`); else another setting of its entry.
    pub representation: Option<biscale_core::scene::BtfRepresentation>,
}

impl SceneMaterials {
    /// Whether any material has a setting other than dense (then the run makes a BTF study).
    pub fn has_compressed(&self) -> bool {
        self.btfs.iter().any(|b| b.representation != "dense")
    }

    /// The materials with every BTF dense.
    pub fn all_dense(&self) -> Vec<Material> {
        self.materials
            .iter()
            .zip(&self.dense)
            .map(|(m, d)| match d {
                Some(btf) => Material { btf: btf.clone().into(), tiling: m.tiling },
                None => m.clone(),
            })
            .collect()
    }

    /// The materials with every BTF dense except material `variant.material`, which has the
    /// variant's representation.
    pub fn with_variant(&self, variant: &BtfVariant) -> Vec<Material> {
        let mut all = self.all_dense();
        let i = variant.material;
        all[i].btf = variant.representation.clone().unwrap_or_else(|| self.materials[i].btf.clone());
        all
    }
}

impl SceneMaterials {
    /// How the ground-truth reference shades each material (`ReferenceMetrics::shading`):
    /// `<label>: <kind> BRDF, exact` or `<label>: BTF table`, `; `-separated.
    pub fn reference_shading(&self) -> String {
        let one = |(label, brdf): (&String, &Option<Brdf>)| match brdf {
            Some(b) => format!("{label}: {} BRDF, exact", b.kind()),
            None => format!("{label}: BTF table"),
        };
        self.labels.iter().zip(&self.analytic).map(one).collect::<Vec<_>>().join("; ")
    }

    /// One line for reports: `label (btf name)`, comma separated.
    pub fn summary(&self) -> String {
        self.labels
            .iter()
            .zip(&self.materials)
            .map(|(l, m)| if l == m.btf.name() { l.clone() } else { format!("{l} ({})", m.btf.name()) })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

fn shading_err(label: &str) -> impl Fn(biscale_shading::ShadingError) -> PipelineError + '_ {
    move |source| PipelineError::Material { label: label.to_string(), source }
}

/// The generator's input for a synthesized entry on `local_basis` (paths already resolved
/// by the config).
pub fn synth_spec(cfg: &SynthesizedConfig, local_basis: LocalBasis, label: &str) -> Result<BtfSpec> {
    let err = shading_err(label);
    let height_field = match (&cfg.pattern, &cfg.height_map) {
        (Some(p), _) => {
            let pattern = Pattern::from_name(p).map_err(&err)?;
            HeightField::procedural(&Recipe::new(pattern, cfg.amplitude, cfg.frequency, cfg.seed), cfg.resolution)
                .map_err(&err)?
        }
        (None, Some(path)) => HeightField::from_image(path, cfg.amplitude).map_err(&err)?,
        (None, None) => {
            return Err(err(biscale_shading::ShadingError::Invalid(
                "a synthesized entry needs a pattern or a height_map".into(),
            )))
        }
    };
    let albedo_map = match &cfg.albedo_map {
        Some(p) => Some(AlbedoMap::from_image(p).map_err(&err)?),
        None => None,
    };
    let spec = BtfSpec {
        resolution: cfg.resolution,
        local_basis,
        view_grid: (cfg.view_grid > 0).then_some(cfg.view_grid),
        supersample: cfg.supersample,
        interreflection: cfg.interreflection,
        bounce_rays: cfg.bounce_rays,
        albedo_map,
        name: match &cfg.name {
            Some(n) => format!("{n}: {}", describe(cfg)),
            None => describe(cfg),
        },
        ..BtfSpec::new(height_field, cfg.brdf)
    };
    spec.validate().map_err(&err)?;
    Ok(spec)
}

/// A short description of a synthesized entry (reports, the BTF's name).
fn describe(cfg: &SynthesizedConfig) -> String {
    let shape = match (&cfg.pattern, &cfg.height_map) {
        (Some(p), _) => format!("{p} x{} a={}", cfg.frequency, cfg.amplitude),
        (None, Some(h)) => {
            format!("{} a={}", h.file_name().map_or("height map".into(), |n| n.to_string_lossy()), cfg.amplitude)
        }
        _ => String::new(),
    };
    let brdf = match &cfg.brdf {
        Brdf::Lambertian { .. } => "lambertian".to_string(),
        Brdf::Phong { exponent, .. } => format!("phong n={exponent}"),
        Brdf::AshikhminShirley { nu, nv, .. } => format!("ashikhmin-shirley {nu}/{nv}"),
        Brdf::RoughConductor { alpha, .. } => format!("rough conductor a={alpha}"),
        Brdf::RoughPlastic { alpha, .. } => format!("rough plastic a={alpha}"),
    };
    format!("{shape}, {brdf}, {r}x{r}", r = cfg.resolution)
}

/// Cache key of a synthesized entry: the entry (paths resolved), the bytes of the files it
/// names, the local basis and the versions of the generator and the file container.
pub fn synth_key(cfg: &SynthesizedConfig, local_basis: LocalBasis) -> Result<CacheKey> {
    let mut h = ContentHash::default();
    h.write(&SYNTH_VERSION.to_le_bytes());
    h.write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes());
    h.write_str(&local_basis.tag());
    // The label, tiling and representation are not part of the table's meaning: hash the
    // entry without them.
    let unnamed = SynthesizedConfig { name: None, tiling: 1.0, representation: Default::default(), ..cfg.clone() };
    h.write(format!("{unnamed:?}").as_bytes());
    for p in [&cfg.height_map, &cfg.albedo_map].into_iter().flatten() {
        let bytes = biscale_core::io::read_regular(p, u64::MAX, "height or albedo map")
            .map_err(|source| PipelineError::Io { path: p.clone(), source })?;
        h.write(&bytes);
    }
    Ok(CacheKey::new(h.finish128(), format!("synthesized BTF ({}) on {local_basis}", describe(cfg))))
}

/// Where a material's table came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// Tabulated from an analytic BRDF (no ray tracing).
    Analytic,
    /// Ray traced now, in this many seconds.
    Synthesized { seconds: f64 },
    /// Loaded from this cache file.
    Cached(PathBuf),
    /// Resampled from measured images now.
    Measured(biscale_shading::measured::BonnReport, f64),
}

/// The BTF of one entry on `local_basis`; synthesized tables are cached when there is a
/// cache. `label` names the entry in messages and progress.
pub fn material_btf(
    cfg: &MaterialConfig,
    local_basis: LocalBasis,
    cache: Option<&StageCache>,
    label: &str,
) -> Result<(Btf, Origin)> {
    let err = shading_err(label);
    let core_err = |e: biscale_core::CoreError| err(e.into());
    match cfg {
        MaterialConfig::Lambertian { albedo, .. } => {
            Ok((Btf::lambertian(*albedo, local_basis).map_err(core_err)?, Origin::Analytic))
        }
        MaterialConfig::Phong { kd, ks, exponent, view_grid, .. } => {
            Ok((Btf::phong(*kd, *ks, *exponent, local_basis, *view_grid).map_err(core_err)?, Origin::Analytic))
        }
        MaterialConfig::Bonn(b) => {
            let opts = biscale_shading::measured::BonnImport {
                local_basis,
                view_grid: b.view_grid,
                resolution: b.resolution,
                scale: b.scale,
                name: label.to_string(),
            };
            let start = Instant::now();
            let (btf, report) = biscale_shading::measured::load_bonn(&b.path, &opts).map_err(&err)?;
            Ok((btf, Origin::Measured(report, start.elapsed().as_secs_f64())))
        }
        MaterialConfig::Synthesized(s) => {
            let encoding = BtfEncoding::from_name(&s.encoding).map_err(&err)?;
            let key = synth_key(s, local_basis)?;
            let path = cache.map(|c| c.btf_path(&key, &s.encoding));
            if let (Some(c), Some(p)) = (cache, &path) {
                let accept = |b: &Btf| match b.local_basis() == local_basis {
                    true => Ok(()),
                    false => {
                        Err(format!("{}: a BTF on {}, this run needs {local_basis}", p.display(), b.local_basis()))
                    }
                };
                if let Some(btf) = c.get(p, &key, btf_from_artifact, accept) {
                    return Ok((btf, Origin::Cached(p.clone())));
                }
            }
            let spec = synth_spec(s, local_basis, label)?;
            let texels = if spec.height_field.is_flat() && spec.albedo_map.is_none() {
                1
            } else {
                (spec.resolution as u64).pow(2)
            };
            let pb = progress_bar(texels, &format!("btf {label}"));
            let tick = |done: usize| pb.set_position(done as u64);
            let start = Instant::now();
            let btf = synthesize(&spec, Some(&tick)).map_err(&err)?;
            let seconds = start.elapsed().as_secs_f64();
            pb.finish_and_clear();
            // Use exactly what the encoding stores, cached or not.
            let stored = btf_artifact(&btf, encoding).map_err(&err)?;
            let source = path.clone().unwrap_or_else(|| PathBuf::from(format!("<{label} in memory>")));
            if let (Some(c), Some(p)) = (cache, &path) {
                c.put(p, &key, &stored);
            }
            let btf = btf_from_artifact(Artifact { source, ..stored }).map_err(&err)?;
            Ok((btf, Origin::Synthesized { seconds }))
        }
    }
}

/// Which config entry each of the mesh's material names uses (`None` = one entry for all).
/// Errors name the OBJ and the material when an OBJ material has no entry.
pub fn assign(mesh: &Mesh, mesh_path: &Path, configs: &[MaterialConfig]) -> Result<Option<Vec<usize>>> {
    let single_unnamed = configs.len() == 1 && configs[0].name().is_none();
    match &mesh.materials {
        _ if single_unnamed => Ok(None),
        None if configs.len() == 1 => Ok(None),
        None => Err(PipelineError::Mismatch {
            path: mesh_path.to_path_buf(),
            what: format!(
                "the config names {} materials but the OBJ has no usemtl or groups to tell them apart",
                configs.len()
            ),
        }),
        Some(ids) => {
            let counts = ids.counts();
            let mut of_name = Vec::with_capacity(ids.names.len());
            for (name, count) in ids.names.iter().zip(counts) {
                match configs.iter().position(|c| c.name() == Some(name.as_str())) {
                    Some(i) => of_name.push(i),
                    None => {
                        let named: Vec<_> = configs.iter().filter_map(|c| c.name()).collect();
                        return Err(PipelineError::Mismatch {
                            path: mesh_path.to_path_buf(),
                            what: format!(
                                "material \"{name}\" ({count} triangles) is not named by any [[scene.materials]] entry (the config names: {})",
                                if named.is_empty() { "none".to_string() } else { named.join(", ") }
                            ),
                        });
                    }
                }
            }
            Ok(Some(of_name))
        }
    }
}

/// Build the experiment's materials for `mesh` on `local_basis` (`T`'s; see the module docs).
pub fn load_materials(
    exp: &Experiment,
    mesh: &Mesh,
    local_basis: LocalBasis,
    cache: Option<&StageCache>,
) -> Result<SceneMaterials> {
    let configs = exp.materials();
    let mut notes = vec![];
    let of_name = assign(mesh, &exp.mesh_path, &configs)?;
    // Which entries are used, in config order, and the compact index of each.
    let used: Vec<bool> = match (&of_name, &mesh.materials) {
        (Some(map), Some(ids)) => {
            let counts = ids.counts();
            (0..configs.len()).map(|c| map.iter().zip(&counts).any(|(&m, &n)| m == c && n > 0)).collect()
        }
        _ => (0..configs.len()).map(|c| c == 0).collect(),
    };
    let mut compact = vec![u32::MAX; configs.len()];
    let (mut materials, mut labels, mut btfs, mut variants, mut dense) = (vec![], vec![], vec![], vec![], vec![]);
    let mut analytic = vec![];
    for (c, cfg) in configs.iter().enumerate() {
        let label = cfg.label();
        if !used[c] {
            notes.push(format!("material {label}: left out, no triangle uses it"));
            continue;
        }
        let (btf, origin) = material_btf(cfg, local_basis, cache, &label)?;
        match &origin {
            Origin::Analytic => {}
            Origin::Synthesized { seconds } => log::info!("btf {label}: synthesized in {seconds:.1} s"),
            Origin::Cached(p) => log::info!("btf {label}: loaded from cache {}", p.display()),
            Origin::Measured(r, seconds) => log::info!(
                "btf {label}: resampled {} views x {} lights of {}x{} images in {seconds:.1} s (farthest bin centre {:.1} deg from a measured direction)",
                r.views,
                r.lights,
                r.image_size[0],
                r.image_size[1],
                r.max_interpolation_angle_deg
            ),
        }
        if btf.view_grid().is_none() {
            notes.push(format!("material {label}: view axis left out (view-independent BTF)"));
        }
        if let MaterialConfig::Synthesized(s) = cfg {
            if btf.texel_count() == 1 && s.albedo_map.is_none() {
                notes.push(format!("material {label}: flat patch, tabulated analytically (no ray tracing)"));
            }
            if matches!(s.brdf, Brdf::AshikhminShirley { .. }) && mesh.uvs.is_none() {
                notes.push(format!(
                    "material {label}: anisotropic BRDF on a mesh without texture coordinates: tangents come from the \
                     fixed-axis field (smooth, but the anisotropy direction is not authored)"
                ));
            }
        }
        if mesh.uvs.is_none() && btf.texel_count() > 1 {
            notes.push(format!(
                "material {label}: the mesh has no texture coordinates, so every point shows texel 0 of the patch"
            ));
        }
        let index = materials.len();
        let mut own = None;
        for (i, &repr) in cfg.representations().all().iter().enumerate() {
            let (r, mut record) = represent(&btf, repr, exp.file.seed, cache, &label)?;
            record.primary = i == 0;
            btfs.push(record);
            match i {
                0 => {
                    variants.push(BtfVariant { material: index, representation: None });
                    own = Some(r);
                }
                _ => variants.push(BtfVariant { material: index, representation: Some(r) }),
            }
        }
        let own = own.expect("a representation list is never empty");
        compact[c] = index as u32;
        dense.push(match own {
            biscale_core::scene::BtfRepresentation::Dense(_) => None,
            _ => Some(btf),
        });
        materials.push(Material { btf: own, tiling: cfg.tiling() });
        analytic.push(analytic_brdf(cfg));
        labels.push(label);
    }
    let triangle_materials = match (&of_name, &mesh.materials) {
        (Some(map), Some(ids)) if materials.len() > 1 => {
            Some(ids.per_triangle.iter().map(|&i| compact[map[i as usize]]).collect())
        }
        _ => {
            notes.push("material ids: left out, the scene uses one material".into());
            None
        }
    };
    Ok(SceneMaterials { materials, triangle_materials, labels, notes, btfs, variants, dense, analytic })
}

/// `btf` in the representation `repr`: dense as it is, or compressed by local PCA (cached by
/// content), which every shader then evaluates from its eigen-BRDFs. The record says what it
/// costs and loses.
pub(crate) fn represent(
    btf: &Btf,
    repr: RepresentationSetting,
    seed: u64,
    cache: Option<&StageCache>,
    label: &str,
) -> Result<(biscale_core::scene::BtfRepresentation, crate::metrics::BtfRecord)> {
    let dense_bytes = (btf.data().len() * 12) as u64;
    let mut record = crate::metrics::BtfRecord {
        material: label.to_string(),
        representation: repr.label(),
        dense_bytes,
        bytes: dense_bytes,
        compression_ratio: 1.0,
        relative_rms_error: 0.0,
        build_seconds: 0.0,
        primary: false,
        study: None,
    };
    let RepresentationSetting::Lpca(asked) = repr else {
        return Ok((btf.clone().into(), record));
    };
    let err = shading_err(label);
    // One f32 fit per setting serves every storage width (cached under the f32 label);
    // quantizing it is cheap.
    let (settings, q) = (LpcaSettings { quantize: LpcaQuantize::F32, ..asked }, asked.quantize);
    let f32_label = RepresentationSetting::Lpca(settings).label();
    let key = lpca_key(btf, &settings, seed);
    let path = cache.map(|c| c.lpca_path(&key, &f32_label));
    let cached = match (cache, &path) {
        (Some(c), Some(p)) => c.get(p, &key, LpcaBtf::from_artifact, |l| match l.fits(btf) {
            true => Ok(()),
            false => Err(format!("{}: an LPCA BTF of another shape than {}", p.display(), btf.name())),
        }),
        _ => None,
    };
    let (lpca, seconds, how) = match cached {
        Some(l) => (l, 0.0, "loaded from cache".to_string()),
        None => {
            let (l, report) = LpcaBtf::compress(btf, &settings, seed).map_err(|e| err(e.into()))?;
            if let (Some(c), Some(p)) = (cache, &path) {
                c.put(p, &key, &l.to_artifact());
            }
            (l, report.seconds, format!("in {:.1} s", report.seconds))
        }
    };
    let lpca = if q == LpcaQuantize::F32 { lpca } else { lpca.quantized(q).map_err(|e| err(e.into()))? };
    record.bytes = lpca.bytes();
    record.compression_ratio = dense_bytes as f64 / lpca.bytes().max(1) as f64;
    record.relative_rms_error = lpca.table_error(btf).0;
    record.build_seconds = seconds;
    log::info!(
        "btf {label}: {} {how}: {:.2} MB of {:.2} MB (1:{:.0}), relative RMS error {:.2}%",
        record.representation,
        record.bytes as f64 * 1e-6,
        dense_bytes as f64 * 1e-6,
        record.compression_ratio,
        100.0 * record.relative_rms_error
    );
    Ok((lpca.into(), record))
}

/// Bump when the meaning of a stored LPCA BTF changes.
const LPCA_VERSION: u32 = 2; // 2: one power iteration, oversampling 4

/// Cache key of a local-PCA BTF: the dense table's content and shape, the setting and the
/// seed (the build is deterministic for them on any number of threads).
pub fn lpca_key(btf: &Btf, settings: &LpcaSettings, seed: u64) -> CacheKey {
    let mut h = ContentHash::default();
    h.write(&LPCA_VERSION.to_le_bytes())
        .write(&biscale_core::artifact::CONTAINER_VERSION.to_le_bytes())
        .write_str(&btf.local_basis().tag())
        .write_str(&format!("{:?} {:?} {settings:?} {seed}", btf.spatial(), btf.view_grid().map(|g| g.m)));
    for v in btf.data() {
        for x in v {
            h.write(&x.to_le_bytes());
        }
    }
    CacheKey::new(h.finish128(), format!("local PCA ({settings:?}, seed {seed}) of the BTF '{}'", btf.name()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cache key of a synthesized table depends on what makes the table, not on how it is
    /// named, tiled or represented for shading (a new representation must not re-trace it).
    #[test]
    fn synth_key_ignores_name_tiling_and_representation() {
        let toml = |extra: &str| -> SynthesizedConfig {
            toml::from_str(&format!(
                "pattern = \"bumps\"\namplitude = 0.05\nbrdf = {{ kind = \"lambertian\", albedo = [0.5, 0.5, 0.5] }}\n{extra}"
            ))
            .unwrap()
        };
        let basis = LocalBasis::bins(4).unwrap();
        let base = synth_key(&toml(""), basis).unwrap();
        let same = toml("name = \"x\"\ntiling = 3.0\nrepresentation = { kind = \"lpca\", clusters = 2 }");
        assert_eq!(synth_key(&same, basis).unwrap().hash, base.hash);
        assert_ne!(synth_key(&toml("resolution = 16"), basis).unwrap().hash, base.hash);
    }
}
