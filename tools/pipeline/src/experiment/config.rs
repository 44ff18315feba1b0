//! Experiment configuration: one TOML file per experiment (docs/DESIGN.md section 7).
//!
//! Every table denies unknown keys; type errors, unknown keys, out-of-range values and
//! missing files are reported as `file:line:column: message` with the offending line shown.
//! Paths in a config are relative to the config file's folder.
//!
//! ```toml
//! name = "bunny"
//! [scene]
//! mesh = "../assets/meshes/bunny.obj"   # or a .ply
//! [scene.material]                 # or several [[scene.materials]], each with a name
//! kind = "lambertian"
//! albedo = [0.8, 0.8, 0.8]
//! [lighting]
//! env_map = "../assets/envmaps/blender_forest.exr"   # lat-long, a cube cross, or "sky_{face}.exr"
//! [[compressors]]
//! kind = "sparse"
//! ```

use biscale_compressors::registry::Role;
use biscale_core::scene::{LpcaQuantize, LpcaSettings, LpcaUnit};
use biscale_shading::synth::Brdf;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// A config error with its location, rendered like a compiler diagnostic: `file:line:column:
/// message` and the line with a caret, or `--set KEY: message` for a value set on the command
/// line (`line` 0).
#[derive(Debug, thiserror::Error)]
#[error("{}", self.render())]
pub struct ConfigError {
    pub file: String,
    pub line: usize,
    pub column: usize,
    pub message: String,
    pub snippet: String,
}

impl ConfigError {
    fn render(&self) -> String {
        match self.line {
            0 => format!("{}: {}", self.file, self.message),
            _ => format!("{}:{}:{}: {}\n{}", self.file, self.line, self.column, self.message, self.snippet),
        }
    }

    /// An error of the value `--set KEY=...` gave.
    fn of_override(key: &str, message: impl Into<String>) -> Self {
        Self {
            file: format!("--set {key}"),
            line: 0,
            column: 0,
            message: cut_message(message.into()),
            snippet: String::new(),
        }
    }

    /// An error at byte range `span` of `source`.
    pub fn at(file: &Path, source: &str, span: Range<usize>, message: impl Into<String>) -> Self {
        let start = span.start.min(source.len());
        let line_start = source[..start].rfind('\n').map_or(0, |i| i + 1);
        let line = source[..start].matches('\n').count() + 1;
        let column = source[line_start..start].chars().count() + 1;
        let line_end = source[start..].find('\n').map_or(source.len(), |i| start + i);
        let text: Vec<char> = source[line_start..line_end].chars().collect();
        let width = source[start..span.end.min(line_end).max(start)].chars().count().max(1);
        // A long line is shown as a window around the error, so a 50 MB line does not make a
        // 50 MB message.
        let (from, to) = match text.len() > SNIPPET_CHARS {
            false => (0, text.len()),
            true => {
                let from = (column - 1).saturating_sub(SNIPPET_CHARS / 3).min(text.len() - SNIPPET_CHARS);
                (from, from + SNIPPET_CHARS)
            }
        };
        let lead = if from > 0 { "..." } else { "" };
        let tail = if to < text.len() { "..." } else { "" };
        let shown: String = text[from..to].iter().collect();
        let caret_at = lead.len() + (column - 1).saturating_sub(from);
        let carets = width.min(to.saturating_sub(column - 1).max(1));
        let snippet = format!("{line:>4} | {lead}{shown}{tail}\n     | {}{}", " ".repeat(caret_at), "^".repeat(carets));
        Self { file: file.display().to_string(), line, column, message: cut_message(message.into()), snippet }
    }

    fn whole_file(file: &Path, message: impl Into<String>) -> Self {
        Self {
            file: file.display().to_string(),
            line: 1,
            column: 1,
            message: cut_message(message.into()),
            snippet: String::new(),
        }
    }
}

/// Settings that only make sense for some transfer shapes, checked at load (so `plan` reports
/// them, not the compressor after the transfer is traced): each kind's own limits
/// (`registry::Kind::fits`, e.g. CPCA's components and Haar's terms), named by the setting.
fn check_against_transfer(
    setting: &Setting,
    transfer: &biscale_core::transfer::TransferSettings,
) -> std::result::Result<(), String> {
    fits_of(biscale_compressors::registry::find(&setting.kind), setting, transfer)
}

/// [`check_against_transfer`] with the kind given (a kind the registry does not know has no
/// limits here: building it fails with its own message).
pub(crate) fn fits_of(
    kind: Option<&biscale_compressors::registry::Kind>,
    setting: &Setting,
    transfer: &biscale_core::transfer::TransferSettings,
) -> std::result::Result<(), String> {
    match kind {
        Some(kind) => (kind.fits)(&setting.params, transfer).map_err(|e| format!("{}: {e}", setting.label)),
        None => Ok(()),
    }
}

/// Most characters of a config line an error shows.
const SNIPPET_CHARS: usize = 120;
/// Most characters of an error message (a parser's message can quote a whole value).
const MESSAGE_CHARS: usize = 400;

/// `message`, with its middle cut out when it is longer than [`MESSAGE_CHARS`].
fn cut_message(message: String) -> String {
    let n = message.chars().count();
    if n <= MESSAGE_CHARS {
        return message;
    }
    let head: String = message.chars().take(MESSAGE_CHARS / 2).collect();
    let tail: String = message.chars().skip(n - MESSAGE_CHARS / 4).collect();
    format!("{head} ... ({} characters cut) ... {tail}", n - MESSAGE_CHARS / 2 - MESSAGE_CHARS / 4)
}

/// The whole experiment file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentFile {
    /// Experiment name: the default output folder is `out/<name>/`.
    pub name: Spanned<String>,
    /// Seed for every random choice in the run.
    #[serde(default)]
    pub seed: u64,
    pub scene: SceneConfig,
    pub lighting: LightingConfig,
    #[serde(default)]
    pub transfer: TransferConfig,
    /// `[[compressors]]` entries: `kind` plus the compressor's own keys (see
    /// [`CompressorTable`]).
    #[serde(default)]
    pub compressors: Vec<Spanned<CompressorTable>>,
    /// `[[methods]]` entries: rendering methods beside the all-frequency one (`kind = "sh"`
    /// plus the method's keys, swept like a compressor's; see `crate::experiment::methods`).
    #[serde(default)]
    pub methods: Vec<Spanned<CompressorTable>>,
    #[serde(default)]
    pub runtime: RuntimeConfig,
    #[serde(default)]
    pub report: ReportConfig,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// OBJ or PLY mesh, relative to the config file.
    pub mesh: Spanned<PathBuf>,
    /// One material for the whole mesh (ignores the OBJ's material names).
    #[serde(default)]
    pub material: Option<Spanned<MaterialConfig>>,
    /// Several materials, matched by `name` to the OBJ's `usemtl` (or group) names.
    #[serde(default)]
    pub materials: Vec<Spanned<MaterialConfig>>,
}

/// One material: a BTF (analytic or synthesized) and its tiling.
///
/// `name` matches the OBJ's `usemtl` names (or its `g`/`o` groups when it has no `usemtl`;
/// faces before any `usemtl` are named `default`); it may be left out when the scene has one
/// material. `tiling` is the number of patch repetitions per unit of texture coordinate.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MaterialConfig {
    /// View-independent diffuse BTF: `albedo / pi * cos`.
    Lambertian {
        #[serde(default)]
        name: Option<String>,
        albedo: [f32; 3],
        #[serde(default = "default_tiling")]
        tiling: f32,
        #[serde(default)]
        representation: Representations,
    },
    /// Normalized modified Phong, view-dependent (`view_grid` x `view_grid` view samples).
    Phong {
        #[serde(default)]
        name: Option<String>,
        kd: [f32; 3],
        ks: [f32; 3],
        exponent: f32,
        #[serde(default = "default_view_grid")]
        view_grid: u32,
        #[serde(default = "default_tiling")]
        tiling: f32,
        #[serde(default)]
        representation: Representations,
    },
    /// A BTF ray traced from a tileable height-field patch (`biscale_shading::synth`),
    /// generated on demand and cached by content.
    Synthesized(SynthesizedConfig),
    /// A measured BTF in the Bonn BTF Database layout (`biscale_shading::measured::bonn`),
    /// resampled onto `T`'s light bins and a view grid when the run starts.
    Bonn(BonnConfig),
}

/// The parameters of a measured BTF in the Bonn layout (a folder per view,
/// `tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg`, ...).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BonnConfig {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default = "default_tiling")]
    pub tiling: f32,
    /// The sample's folder (relative to the config file).
    pub path: PathBuf,
    /// Texels per patch side: the images are box-filtered down to it (it must divide their size).
    #[serde(default = "default_resolution")]
    pub resolution: u32,
    /// View grid side the measured views are resampled onto; 0 keeps the view nearest the
    /// normal alone (no view axis).
    #[serde(default = "default_view_grid")]
    pub view_grid: u32,
    /// Multiplies every value: image units to radiance under unit perpendicular irradiance.
    #[serde(default = "default_scale")]
    pub scale: f32,
    #[serde(default)]
    pub representation: Representations,
}

fn default_scale() -> f32 {
    1.0
}

/// The parameters of a synthesized BTF (see `biscale_shading::synth::BtfSpec`).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SynthesizedConfig {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default = "default_tiling")]
    pub tiling: f32,
    /// Procedural pattern: bumps, weave, stucco, holes, bricks, scales (or `height_map`).
    #[serde(default)]
    pub pattern: Option<String>,
    /// Grayscale height image (relative to the config file) instead of a pattern.
    #[serde(default)]
    pub height_map: Option<PathBuf>,
    /// Height scale in patch units (0 gives a flat patch, tabulated analytically).
    pub amplitude: f32,
    /// Features per patch side (pattern only).
    #[serde(default = "default_frequency")]
    pub frequency: u32,
    #[serde(default)]
    pub seed: u64,
    /// Texels per patch side (32 or 64 in the paper's setting).
    #[serde(default = "default_resolution")]
    pub resolution: u32,
    /// View grid side; 0 drops the view axis (the diffuse special case, Lambertian only).
    #[serde(default = "default_view_grid")]
    pub view_grid: u32,
    /// View rays per texel side.
    #[serde(default = "default_supersample")]
    pub supersample: u32,
    /// One bounce of meso-scale interreflection.
    #[serde(default)]
    pub interreflection: bool,
    #[serde(default = "default_bounce_rays")]
    pub bounce_rays: u32,
    /// Color texture scaling the diffuse term (relative to the config file).
    #[serde(default)]
    pub albedo_map: Option<PathBuf>,
    /// How the table is stored in the cache and used: f32, f16 (default) or u8.
    #[serde(default = "default_encoding")]
    pub encoding: String,
    /// The meso-scale BRDF.
    pub brdf: Brdf,
    /// How the table is held for shading: `dense` (default) or `lpca`; a list compares
    /// several (the first is the one every compressor is shaded with).
    #[serde(default)]
    pub representation: Representations,
}

/// Which representation of a material's BTF to build and shade with (`representation = {
/// kind = "lpca", ... }`): the setting, where [`biscale_core::scene::RepresentationSetting`] is
/// the table built from it.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RepresentationSetting {
    /// The table as tabulated, `[texel][view][light]`.
    #[default]
    Dense,
    /// Local PCA (Müller et al. 2004): `clusters` texel clusters of a mean and `components`
    /// eigen-BRDFs each (`biscale_core::scene::lpca`); every key optional.
    Lpca(LpcaSettings),
}

/// One representation or a list of them (`representation = { .. }` or `[{ .. }, { .. }]`):
/// the first is the material's own (every compressor and method is shaded with it), the others
/// are compared with it in the BTF study of the run. Never empty.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Representations(Vec<RepresentationSetting>);

impl Default for Representations {
    fn default() -> Self {
        Self(vec![RepresentationSetting::Dense])
    }
}

impl From<RepresentationSetting> for Representations {
    fn from(r: RepresentationSetting) -> Self {
        Self(vec![r])
    }
}

impl Representations {
    /// The material's own representation (the first).
    pub fn primary(&self) -> RepresentationSetting {
        self.0[0]
    }

    pub fn all(&self) -> &[RepresentationSetting] {
        &self.0
    }
}

impl<'de> Deserialize<'de> for Representations {
    /// A table or an array of tables; each keeps serde's own messages (unknown keys, bad
    /// kinds) with their position.
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = Representations;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a representation table or a non-empty array of them")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
                RepresentationSetting::deserialize(serde::de::value::MapAccessDeserializer::new(map)).map(Into::into)
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut all = vec![];
                while let Some(r) = seq.next_element::<RepresentationSetting>()? {
                    all.push(r);
                }
                if all.is_empty() {
                    return Err(serde::de::Error::invalid_length(0, &self));
                }
                Ok(Representations(all))
            }
        }
        d.deserialize_any(Visitor)
    }
}

impl RepresentationSetting {
    /// The label in messages and metrics: `dense`, `lpca-k16-c4`.
    pub fn label(&self) -> String {
        match self {
            Self::Dense => "dense".into(),
            Self::Lpca(LpcaSettings { clusters, components, unit, quantize, iterations }) => {
                let mut label = format!("lpca-k{clusters}-c{components}");
                if *iterations != biscale_core::scene::DEFAULT_LPCA_ITERATIONS {
                    label += &format!("-i{iterations}");
                }
                if *unit == LpcaUnit::View {
                    label += "-view";
                }
                match quantize {
                    LpcaQuantize::F32 => {}
                    LpcaQuantize::F16 => label += "-f16",
                    LpcaQuantize::U8 => label += "-u8",
                }
                label
            }
        }
    }
}

fn default_view_grid() -> u32 {
    12
}
fn default_tiling() -> f32 {
    1.0
}
fn default_frequency() -> u32 {
    4
}
fn default_resolution() -> u32 {
    32
}
fn default_supersample() -> u32 {
    2
}
fn default_bounce_rays() -> u32 {
    16
}
fn default_encoding() -> String {
    "f16".into()
}

impl Default for MaterialConfig {
    fn default() -> Self {
        MaterialConfig::Lambertian {
            name: None,
            albedo: [0.8, 0.8, 0.8],
            tiling: 1.0,
            representation: Representations::default(),
        }
    }
}

impl MaterialConfig {
    /// The OBJ material name this entry matches, if given.
    pub fn name(&self) -> Option<&str> {
        match self {
            MaterialConfig::Lambertian { name, .. } | MaterialConfig::Phong { name, .. } => name.as_deref(),
            MaterialConfig::Synthesized(s) => s.name.as_deref(),
            MaterialConfig::Bonn(b) => b.name.as_deref(),
        }
    }

    /// How the entry's BTF is represented for shading (the first of its list).
    pub fn representation(&self) -> RepresentationSetting {
        self.representations().primary()
    }

    /// Every representation the entry lists (the first is its own).
    pub fn representations(&self) -> &Representations {
        match self {
            MaterialConfig::Lambertian { representation, .. } | MaterialConfig::Phong { representation, .. } => {
                representation
            }
            MaterialConfig::Synthesized(s) => &s.representation,
            MaterialConfig::Bonn(b) => &b.representation,
        }
    }

    pub fn tiling(&self) -> f32 {
        match self {
            MaterialConfig::Lambertian { tiling, .. } | MaterialConfig::Phong { tiling, .. } => *tiling,
            MaterialConfig::Synthesized(s) => s.tiling,
            MaterialConfig::Bonn(b) => b.tiling,
        }
    }

    /// `lambertian`, `phong`, `synthesized` or `bonn`.
    pub fn kind(&self) -> &'static str {
        match self {
            MaterialConfig::Lambertian { .. } => "lambertian",
            MaterialConfig::Phong { .. } => "phong",
            MaterialConfig::Synthesized(_) => "synthesized",
            MaterialConfig::Bonn(_) => "bonn",
        }
    }

    /// A label for plans and reports: the name, else the kind.
    pub fn label(&self) -> String {
        self.name().map_or_else(|| self.kind().to_string(), str::to_string)
    }
}

/// What is wrong with a material entry, if anything (ranges only; files are checked by the
/// caller, which resolves their paths).
fn check_material(m: &MaterialConfig) -> Result<(), String> {
    let rgb_ok = |v: &[f32; 3]| v.iter().all(|x| x.is_finite() && *x >= 0.0);
    if !(m.tiling().is_finite() && m.tiling() > 0.0) {
        return Err(format!("tiling must be a positive finite number, got {}", m.tiling()));
    }
    if let Some(n) = m.name() {
        if n.trim().is_empty() {
            return Err("name must not be empty".into());
        }
    }
    let all = m.representations().all();
    // Each setting is a local-PCA build, a copy of the scene with its own dot products and
    // images in the BTF study: a list is capped like a sweep.
    if all.len() > MAX_SWEEP_SETTINGS {
        return Err(format!(
            "the representation list of {} has {} settings, over the limit of {MAX_SWEEP_SETTINGS} settings of one \
             entry; split the study or shorten the list",
            m.label(),
            all.len()
        ));
    }
    for (i, r) in all.iter().enumerate() {
        if let RepresentationSetting::Lpca(LpcaSettings { clusters, components, iterations, .. }) = *r {
            if clusters == 0 || clusters > u16::MAX as usize - 1 {
                return Err(format!("lpca clusters = {clusters} must be in 1..=65534"));
            }
            if !(1..=1000).contains(&iterations) {
                return Err(format!("lpca iterations = {iterations} must be in 1..=1000"));
            }
            if components == 0 {
                return Err("lpca components must be at least 1".into());
            }
        }
        if all[..i].contains(r) {
            return Err(format!("representation {} is listed twice", r.label()));
        }
    }
    match m {
        MaterialConfig::Lambertian { albedo, .. } if !rgb_ok(albedo) => Err("albedo must be finite and >= 0".into()),
        MaterialConfig::Bonn(b) => {
            if !(1..=1024).contains(&b.resolution) {
                Err(format!("resolution must be in 1..=1024, got {}", b.resolution))
            } else if b.view_grid > 64 {
                Err(format!("view_grid must be in 0..=64 (0: no view axis), got {}", b.view_grid))
            } else if !(b.scale.is_finite() && b.scale >= 0.0) {
                Err(format!("scale must be finite and >= 0, got {}", b.scale))
            } else {
                Ok(())
            }
        }
        MaterialConfig::Phong { kd, ks, exponent, view_grid, .. } => {
            if !(exponent.is_finite() && *exponent >= 0.0) || *view_grid == 0 || *view_grid > 64 {
                Err("phong needs exponent >= 0 and view_grid in 1..=64".into())
            } else if !rgb_ok(kd) || !rgb_ok(ks) {
                Err("kd and ks must be finite and >= 0".into())
            } else {
                Ok(())
            }
        }
        MaterialConfig::Synthesized(s) => {
            match (&s.pattern, &s.height_map) {
                (Some(_), Some(_)) => return Err("give either pattern or height_map, not both".into()),
                (None, None) => {
                    return Err("a synthesized material needs pattern = \"...\" or height_map = \"...\"".into())
                }
                _ => {}
            }
            if !(s.amplitude.is_finite() && s.amplitude >= 0.0) {
                return Err(format!("amplitude must be finite and >= 0, got {}", s.amplitude));
            }
            if !(1..=1024).contains(&s.resolution) {
                return Err(format!("resolution must be in 1..=1024, got {}", s.resolution));
            }
            if s.view_grid > 64 {
                return Err(format!("view_grid must be in 0..=64 (0: no view axis), got {}", s.view_grid));
            }
            if s.view_grid == 0 && !matches!(s.brdf, Brdf::Lambertian { .. }) {
                return Err("view_grid = 0 (no view axis) needs a lambertian brdf".into());
            }
            if !["f32", "f16", "u8"].contains(&s.encoding.as_str()) {
                return Err(format!("encoding must be f32, f16 or u8, got {:?}", s.encoding));
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightingConfig {
    /// EXR or HDR environment map (relative to the config file): lat-long (2:1), a cube-map
    /// cross (4:3 or 3:4), or six cube faces when the file name holds `{face}`
    /// (`sky_{face}.exr`: `px nx py ny pz nz`; `biscale_core::sampling::cube_env`).
    pub env_map: Option<Spanned<PathBuf>>,
    /// A constant sky of this radiance instead of a map.
    pub constant: Option<[f32; 3]>,
    /// Rotation of the environment about +Y, degrees.
    #[serde(default)]
    pub rotation_degrees: f64,
    /// Multiply the brightest cubemap texel by this factor (the stiff "sun" case).
    pub sun_boost: Option<Spanned<f32>>,
    /// Where light moments take each cubemap texel's light from: `centre` (default: the
    /// texel's centre, as `T` bins it) or `mean` (the power-weighted mean direction of the
    /// source pixels it averages, per channel). Only light moments read it; `T` and the ground
    /// truth do not.
    #[serde(default)]
    pub texel_directions: biscale_core::sampling::TexelDirections,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransferConfig {
    /// Light cubemap resolution R (N = 6 R^2). Reference 32.
    #[serde(default = "default_cubemap")]
    pub cubemap_resolution: Spanned<u32>,
    /// Visibility cubemap resolution (a multiple of R). Reference 64 (2x2 box filter).
    #[serde(default = "default_visibility")]
    pub visibility_resolution: Spanned<u32>,
    /// Local light directions per axis m (M = m^2). Reference 8.
    #[serde(default = "default_local_grid")]
    pub local_grid: Spanned<u32>,
    /// How visibility is decided: "coverage" (default: each face's triangles rasterised into
    /// its coverage mask) or "rays" (every ray traced). The same `T` (docs/DESIGN.md).
    #[serde(default)]
    pub visibility: biscale_core::transfer::Visibility,
}

fn default_cubemap() -> Spanned<u32> {
    Spanned::new(0..0, 32)
}
fn default_visibility() -> Spanned<u32> {
    Spanned::new(0..0, 64)
}
fn default_local_grid() -> Spanned<u32> {
    Spanned::new(0..0, 8)
}

impl Default for TransferConfig {
    fn default() -> Self {
        Self {
            cubemap_resolution: default_cubemap(),
            visibility_resolution: default_visibility(),
            local_grid: default_local_grid(),
            visibility: Default::default(),
        }
    }
}

/// One `[[compressors]]` entry as written: `kind` and the compressor's own keys, each with its
/// place in the file. The compressor parses the keys itself (its parameter type, in its
/// folder of `biscale-compressors`); the config only expands sweeps: a key whose value is a
/// list runs every value, and several lists run every combination (keys in alphabetical
/// order, the first varying slowest).
pub type CompressorTable = BTreeMap<Spanned<String>, Spanned<toml::Value>>;

/// One compressor or method setting after sweep expansion.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// Label used for file names and report rows, e.g. `cpca-k32-c8`, `sh-n5`.
    pub label: String,
    /// The registry kind (`sparse`, `bicluster`, `cpca`, `haar`, `plugin`; `sh`).
    pub kind: String,
    /// The parameters of this setting, as JSON (paths resolved).
    pub params: serde_json::Value,
}

/// A `[[compressors]]` setting.
pub type CompressorSetting = Setting;
/// A `[[methods]]` setting.
pub type MethodSetting = Setting;

/// What the expansion needs of a kind: its name, its cheap check and its label.
struct KindRef {
    name: &'static str,
    check: fn(&serde_json::Value) -> Result<(), String>,
    label: fn(&serde_json::Value) -> Result<String, String>,
    /// A compressor loaded from a library, whose `path` is resolved against the config.
    external: bool,
}

/// The settings of one `[[compressors]]` or `[[methods]]` entry (see [`CompressorTable`]);
/// `what` names the table in messages. Errors are located at the key (or value) they
/// concern.
fn expand_settings(
    entry: &Spanned<CompressorTable>,
    dir: &Path,
    err: &dyn Fn(Range<usize>, String) -> ConfigError,
    what: &str,
    kinds: &[KindRef],
) -> Result<Vec<Setting>, ConfigError> {
    let names = kinds.iter().map(|k| k.name).collect::<Vec<_>>().join("`, `");
    let Some((_, kind_value)) = entry.get_ref().iter().find(|(k, _)| k.get_ref() == "kind") else {
        return Err(err(entry.span(), format!("a {what} needs kind = one of `{names}`")));
    };
    let Some(kind) = kind_value.get_ref().as_str().and_then(|n| kinds.iter().find(|k| k.name == n)) else {
        let got = kind_value.get_ref().to_string();
        return Err(err(kind_value.span(), format!("unknown {what} kind {got}, expected one of `{names}`")));
    };
    // Every key but `kind`, each value a list of sweep values (one for a plain value).
    let mut keys: Vec<(&Spanned<String>, Range<usize>, Vec<serde_json::Value>)> = vec![];
    for (k, v) in entry.get_ref().iter().filter(|(k, _)| k.get_ref() != "kind") {
        let mut values = match v.get_ref() {
            toml::Value::Array(a) if a.is_empty() => {
                return Err(err(v.span(), "a sweep needs at least one value".into()));
            }
            toml::Value::Array(a) => a.clone(),
            one => vec![one.clone()],
        };
        if kind.external && k.get_ref() == "path" {
            // Resolved against the config's folder and made absolute, so the loader opens
            // exactly this file (a bare file name would be searched for on the library path).
            for p in &mut values {
                let Some(rel) = p.as_str() else { continue };
                let full = dir.join(rel);
                let found = full.canonicalize().ok().filter(|f| f.is_file());
                let Some(full) = found else {
                    return Err(err(v.span(), format!("plugin library not found: {}", full.display())));
                };
                *p = toml::Value::String(full.display().to_string());
            }
        }
        let json = values.iter().map(|x| serde_json::to_value(x).expect("a TOML value is JSON")).collect();
        keys.push((k, v.span(), json));
    }
    // Refused before expanding: a sweep is the product of its lists (a typo gave 9 million
    // settings, and `plan` alone 2.5 GB).
    let count = keys.iter().fold(1u128, |n, (_, _, v)| n.saturating_mul(v.len() as u128));
    if count > MAX_SWEEP_SETTINGS as u128 {
        return Err(err(
            entry.span(),
            format!(
                "this {what} entry sweeps {count} settings (the product of its lists), over the limit of \
                 {MAX_SWEEP_SETTINGS}; split it or shorten the lists"
            ),
        ));
    }
    let mut combos = vec![serde_json::Map::new()];
    for (k, _, values) in &keys {
        combos = combos
            .into_iter()
            .flat_map(|c| {
                values.iter().map(move |x| {
                    let mut c = c.clone();
                    c.insert(k.get_ref().clone(), x.clone());
                    c
                })
            })
            .collect();
    }
    let mut settings = vec![];
    for combo in combos {
        let params = serde_json::Value::Object(combo);
        let checked = (kind.check)(&params).and_then(|()| (kind.label)(&params));
        let label = checked.map_err(|message| {
            // The key the message is about: the one it names (`unknown field `x``), else the
            // one that fails on its own, else the whole entry.
            let named = keys.iter().find(|(k, _, _)| message.contains(&format!("`{}`", k.get_ref())));
            let alone = || {
                keys.iter().find(|(k, _, _)| {
                    let one = serde_json::json!({ k.get_ref().as_str(): params[k.get_ref().as_str()] });
                    (kind.check)(&one).is_err_and(|m| !m.starts_with("missing field"))
                })
            };
            let span = match named.or_else(alone) {
                Some((k, value_span, _)) if message.contains("unknown field") => k.span().start..value_span.end,
                Some((_, value_span, _)) => value_span.clone(),
                None => entry.span(),
            };
            err(span, format!("{} {what}: {message}", kind.name))
        })?;
        if let Some(why) = reserved_label(&label) {
            return Err(err(entry.span(), format!("{} setting `{label}`: {why}", kind.name)));
        }
        settings.push(Setting { label, kind: kind.name.to_string(), params });
    }
    Ok(settings)
}

/// The run's own image names (`images/<name>.png` and `.exr`): no setting may be labelled so,
/// of any kind, or its images would replace the run's (the ground truth among them).
pub const RESERVED_LABELS: [&str; 5] = ["uncompressed", "uncompressed_paper", "reference", "reference_mask", "mask"];

/// Why `label` cannot name a setting, if it cannot ([`RESERVED_LABELS`]).
pub fn reserved_label(label: &str) -> Option<String> {
    RESERVED_LABELS.contains(&label).then(|| {
        format!(
            "the label `{label}` is one of the run's own image names ({}), reserved for every kind; choose another",
            RESERVED_LABELS.join(", ")
        )
    })
}

/// The compressor kinds as the expansion sees them.
fn compressor_kinds() -> Vec<KindRef> {
    biscale_compressors::registry::KINDS
        .iter()
        .map(|k| KindRef { name: k.name, check: k.check, label: k.label, external: k.role == Role::External })
        .collect()
}

/// The method kinds as the expansion sees them.
fn method_kinds() -> Vec<KindRef> {
    crate::experiment::methods::KINDS
        .iter()
        .map(|k| KindRef { name: k.name, check: k.check, label: k.label, external: false })
        .collect()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuntimeConfig {
    /// `cpu` (the reference) or `gpu` (wgpu).
    #[serde(default)]
    pub backend: Backend,
    #[serde(default = "default_width")]
    pub width: Spanned<u32>,
    #[serde(default = "default_height")]
    pub height: Spanned<u32>,
    #[serde(default)]
    pub camera: CameraConfig,
    /// Repetitions for timing the gather and shade (medians are reported).
    #[serde(default = "default_repeats")]
    pub repeats: usize,
    /// Gather the light's three direction moments through the same `T` and weight every texel
    /// by its own cosine instead of its bin's mean cosine (`biscale_core::gather::moments`).
    /// `false` is the paper's shading, kept for reproduction.
    #[serde(default)]
    pub light_moments: bool,
    /// With light moments, where they are resolved into the `L*` the BTF is dotted with:
    /// `vertex` (default: at each vertex, then blended), `pixel` (each vertex's three gathered
    /// moments resolved at every shading point's own frame, then blended; `biscale_shading::
    /// cpu::shade_moments`; CPU backend only) or `pixel_analytic` (as `pixel`, and each bin's light
    /// shaded by a flat analytic material's own BRDF at its mean direction and the pixel's
    /// view instead of the BTF's tables; `shade_moments_analytic`).
    #[serde(default)]
    pub moments_resolve: Option<Spanned<MomentsResolve>>,
    /// Rays per pixel for anti-aliasing, a square (1, 4, 9, ...; a stratified box filter,
    /// `biscale_core::scene::Camera`; the wgpu shader runs on the supersampled grid). Default 4:
    /// see [`RuntimeConfig::samples_per_pixel`].
    pub samples_per_pixel: Option<Spanned<u32>>,
    /// Animated comparisons: the light rotated and the camera orbited, every named setting
    /// rendered per frame beside the uncompressed `T` (`crate::stages::animation`).
    #[serde(default)]
    pub animation: AnimationConfig,
}

/// `[runtime.animation]`: frame sequences of the light rotating about +Y and of the camera
/// orbiting its target, each through one full turn, rendered for the named settings (CPU)
/// and written as animated PNGs with their per-frame error and time.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AnimationConfig {
    /// Frames of the light's turn about +Y (0: none).
    #[serde(default)]
    pub light_frames: u32,
    /// Frames of the camera's orbit about its target (0: none).
    #[serde(default)]
    pub camera_frames: u32,
    /// The compressor and method settings to animate, by label (`bicluster-b1024`, `sh-n5`);
    /// empty: every compressor setting. The uncompressed `T` is always rendered: it is what
    /// every frame's error is measured against.
    #[serde(default)]
    pub settings: Vec<String>,
    /// Playback rate of the animated PNGs, frames per second.
    #[serde(default = "default_animation_fps")]
    pub fps: u32,
}

impl Default for AnimationConfig {
    fn default() -> Self {
        Self { light_frames: 0, camera_frames: 0, settings: vec![], fps: default_animation_fps() }
    }
}

impl AnimationConfig {
    /// Whether any animation is asked for.
    pub fn any(&self) -> bool {
        self.light_frames > 0 || self.camera_frames > 0
    }
}

fn default_animation_fps() -> u32 {
    12
}

/// Most frames of one animation (`runtime.animation.light_frames`, `camera_frames`).
pub const MAX_ANIMATION_FRAMES: u32 = 720;

impl RuntimeConfig {
    /// Whether the run resolves the light moments per pixel (`moments_resolve = "pixel"` or
    /// `"pixel_analytic"`).
    pub fn resolve_per_pixel(&self) -> bool {
        self.light_moments && self.moments_resolve.as_ref().is_some_and(|m| m.get_ref().per_pixel())
    }

    /// Whether the per-pixel resolve shades analytic materials with their own BRDF
    /// (`moments_resolve = "pixel_analytic"`).
    pub fn resolve_analytic(&self) -> bool {
        self.light_moments
            && self.moments_resolve.as_ref().is_some_and(|m| *m.get_ref() == MomentsResolve::PixelAnalytic)
    }

    /// `metrics.json`'s `moments_resolve`: the config's value (default `vertex`), `None`
    /// without light moments.
    pub fn moments_resolve(&self) -> Option<MomentsResolve> {
        self.light_moments.then(|| self.moments_resolve.as_ref().map_or(MomentsResolve::Vertex, |m| *m.get_ref()))
    }

    /// The rays per pixel every render of the run takes: the config's, else 4.
    pub fn samples_per_pixel(&self) -> u32 {
        self.samples_per_pixel.as_ref().map_or(4, |s| *s.get_ref())
    }
}

/// Where light moments are resolved (`runtime.moments_resolve`): the shading crate's type, the
/// one `metrics.json` and the report carry.
pub use biscale_shading::runtime::MomentsResolve;

/// `runtime.backend`: the shading crate's type, the one `metrics.json` and the report carry.
pub use biscale_shading::runtime::Backend;

fn default_width() -> Spanned<u32> {
    Spanned::new(0..0, 640)
}
fn default_height() -> Spanned<u32> {
    Spanned::new(0..0, 480)
}
fn default_repeats() -> usize {
    5
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        Self {
            backend: Backend::Cpu,
            width: default_width(),
            height: default_height(),
            camera: CameraConfig::default(),
            repeats: default_repeats(),
            light_moments: false,
            moments_resolve: None,
            samples_per_pixel: None,
            animation: AnimationConfig::default(),
        }
    }
}

/// Camera: orbit angles around the mesh's bounding sphere, or an explicit position/target.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    #[serde(default = "default_azimuth")]
    pub azimuth_degrees: f32,
    #[serde(default = "default_elevation")]
    pub elevation_degrees: f32,
    #[serde(default = "default_fov")]
    pub fov_y_degrees: f32,
    pub position: Option<[f32; 3]>,
    pub target: Option<[f32; 3]>,
}

fn default_azimuth() -> f32 {
    30.0
}
fn default_elevation() -> f32 {
    20.0
}
fn default_fov() -> f32 {
    35.0
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            azimuth_degrees: default_azimuth(),
            elevation_degrees: default_elevation(),
            fov_y_degrees: default_fov(),
            position: None,
            target: None,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReportConfig {
    /// Trace the per-pixel reference image (slow) and report errors against it.
    #[serde(default)]
    pub reference: bool,
    /// Resolution divisor for the reference image and the images compared with it.
    #[serde(default = "default_one")]
    pub reference_downscale: Spanned<u32>,
    /// Exposure of the PNG images in stops (value x 2^exposure), or `"auto"`: the exposure
    /// that takes the 99th percentile of the uncompressed render's mesh pixels to white.
    #[serde(default)]
    pub exposure: Exposure,
    /// Draw the environment behind the mesh in the images.
    #[serde(default = "default_true")]
    pub background: bool,
    /// Error target of the equal-quality comparison (relative L2 error of L*).
    #[serde(default = "default_target_error")]
    pub target_error: f64,
    /// Full scale of every compressor's error figure (luminance, linear radiance); by default
    /// the largest 99th-percentile error of the lossy settings, shared by all.
    #[serde(default)]
    pub error_scale: Option<f32>,
    /// Full scale of every error figure against the ground truth (luminance, linear
    /// radiance); by default the largest 99th-percentile error of the run's renders (the
    /// uncompressed one, every compressor and method setting), shared by all. Set, it puts
    /// another run's figures on the same colour bar (`biscale reproduce` sets it for a twin).
    #[serde(default)]
    pub reference_error_scale: Option<f32>,
    /// The region `[x, y, width, height]` (pixels of the render) every setting's zoomed inset
    /// shows; by default the window where the worst lossy setting's error is largest.
    #[serde(default)]
    pub inset: Option<Spanned<[u32; 4]>>,
}

/// `[report] exposure`: fixed stops, or chosen by the run from its uncompressed render
/// ([`Exposure::resolve`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exposure {
    Stops(f32),
    Auto,
}

impl Default for Exposure {
    fn default() -> Self {
        Exposure::Stops(0.0)
    }
}

impl Exposure {
    /// The share of the mesh's pixels `"auto"` lets the tone map clip at most.
    pub const AUTO_CLIPS: f64 = 0.01;

    /// The stops to tone map `image` with: fixed, or for `"auto"` the exposure at which at
    /// most [`Self::AUTO_CLIPS`] of the pixels `mask` marks (the mesh) clip
    /// ([`biscale_core::scene::HdrImage::auto_exposure`]).
    pub fn resolve(self, image: &biscale_core::scene::HdrImage, mask: &[bool]) -> f32 {
        match self {
            Exposure::Stops(s) => s,
            Exposure::Auto => image.auto_exposure(Some(mask), 1.0 - Self::AUTO_CLIPS),
        }
    }

    /// The fixed stops; `None` for `"auto"`.
    pub fn stops(self) -> Option<f32> {
        match self {
            Exposure::Stops(s) => Some(s),
            Exposure::Auto => None,
        }
    }
}

impl<'de> Deserialize<'de> for Exposure {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Exposure;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number of stops or \"auto\"")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<Exposure, E> {
                Ok(Exposure::Stops(v as f32))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<Exposure, E> {
                Ok(Exposure::Stops(v as f32))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<Exposure, E> {
                Ok(Exposure::Stops(v as f32))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<Exposure, E> {
                match v {
                    "auto" => Ok(Exposure::Auto),
                    other => Err(E::invalid_value(serde::de::Unexpected::Str(other), &self)),
                }
            }
        }
        d.deserialize_any(V)
    }
}

fn default_target_error() -> f64 {
    0.05
}

fn default_one() -> Spanned<u32> {
    Spanned::new(0..0, 1)
}
fn default_true() -> bool {
    true
}

impl Default for ReportConfig {
    fn default() -> Self {
        Self {
            reference: false,
            reference_downscale: default_one(),
            exposure: Exposure::default(),
            background: true,
            target_error: default_target_error(),
            error_scale: None,
            reference_error_scale: None,
            inset: None,
        }
    }
}

/// A parsed and checked experiment, with paths resolved against the config's folder.
#[derive(Debug)]
pub struct Experiment {
    pub config_path: PathBuf,
    /// The config's text as it runs: the file's, with any `--set` overrides applied.
    pub source: String,
    /// The `--set KEY=VALUE` overrides applied to the file (empty for the file as it is).
    pub overrides: Vec<String>,
    pub file: ExperimentFile,
    pub mesh_path: PathBuf,
    pub env_path: Option<PathBuf>,
    /// `[transfer]` as bases (validated at parse).
    transfer: biscale_core::transfer::TransferSettings,
    /// Every compressor setting, sweeps expanded (checked at parse).
    compressors: Vec<CompressorSetting>,
    /// Every method setting, sweeps expanded (checked at parse).
    methods: Vec<MethodSetting>,
}

/// Most settings one `[[compressors]]` or `[[methods]]` entry may sweep (each is a
/// compression, a gather and an image), and most BTF representations one material may list.
pub const MAX_SWEEP_SETTINGS: usize = 1000;

/// Most timed gathers per setting (`runtime.repeats`): medians settle long before this, and
/// a typo like `10^18` must not run until killed.
pub const MAX_REPEATS: usize = 10_000;

/// Most pixels of one image (`runtime.width x height`): 8192 x 8192, 0.8 GB of f32 RGB.
pub const MAX_PIXELS: u64 = 8192 * 8192;
/// What is wrong with an input file the config names, if anything: `not found`, or what it
/// is when it is not a regular file (a device node, a FIFO, a folder), looked at without
/// opening it, so a FIFO does not block and a device is never read.
fn not_a_file(path: &Path) -> Option<String> {
    match std::fs::metadata(path) {
        Ok(m) => biscale_core::io::not_regular(&m.file_type()).map(|kind| format!("is {kind}, not a regular file")),
        Err(_) => Some("not found".into()),
    }
}

/// The longest experiment name (it names the output folder; file systems take 255 bytes).
pub const MAX_NAME_CHARS: usize = 120;

/// The largest config file read (the bundled ones are a few kilobytes; a sweep's lists stay
/// well under a megabyte).
pub const MAX_CONFIG_BYTES: u64 = 16 << 20;

/// The first non-finite number of a TOML text: its dotted key, its value and the byte range
/// of its literal (`None` for text that is not TOML: the parse reports that).
fn first_non_finite(source: &str) -> Option<(String, f64, Option<Range<usize>>)> {
    use toml_edit::{Item, Value};
    fn value(v: &Value, at: String) -> Option<(String, f64, Option<Range<usize>>)> {
        match v {
            Value::Float(x) if !x.value().is_finite() => Some((at, *x.value(), x.span())),
            Value::Array(a) => a.iter().enumerate().find_map(|(i, x)| value(x, format!("{at}[{i}]"))),
            Value::InlineTable(t) => t.iter().find_map(|(k, x)| value(x, join(&at, k))),
            _ => None,
        }
    }
    fn item(v: &Item, at: String) -> Option<(String, f64, Option<Range<usize>>)> {
        match v {
            Item::Value(x) => value(x, at),
            Item::Table(t) => t.iter().find_map(|(k, x)| item(x, join(&at, k))),
            Item::ArrayOfTables(a) => a
                .iter()
                .enumerate()
                .find_map(|(i, t)| t.iter().find_map(|(k, x)| item(x, join(&format!("{at}[{i}]"), k)))),
            Item::None => None,
        }
    }
    fn join(at: &str, k: &str) -> String {
        if at.is_empty() {
            k.to_string()
        } else {
            format!("{at}.{k}")
        }
    }
    // The document keeps every value's byte span, so the literal is located by the parser
    // itself, not by a second reading of the text.
    let Ok(doc) = toml_edit::ImDocument::parse(source) else { return None };
    item(doc.as_item(), String::new())
}

/// Refuse a config that holds a non-finite number anywhere (`nan`, `inf`, or a literal too big
/// for f64): such a value would flow into the light, the camera or the tone map and give NaN
/// or black images with exit 0. Names the key and the literal's line and column.
fn check_finite(path: &Path, source: &str) -> Result<(), ConfigError> {
    let Some((key, x, span)) = first_non_finite(source) else { return Ok(()) };
    let message = format!("{key} = {x}: every number in a config must be finite");
    Err(match span {
        Some(span) => ConfigError::at(path, source, span, message),
        None => ConfigError::whole_file(path, message),
    })
}

impl Experiment {
    /// Read, parse and validate a config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with(path, &[])
    }

    /// [`Self::load`] with `--set KEY=VALUE` overrides applied to the file's text first
    /// ([`apply_overrides`]); the experiment's `source` is the text with them, so a run's
    /// provenance records the config it really ran.
    pub fn load_with(path: &Path, overrides: &[String]) -> Result<Self, ConfigError> {
        let source = biscale_core::io::read_regular_text(path, MAX_CONFIG_BYTES, "config")
            .map_err(|e| ConfigError::whole_file(path, format!("cannot read config: {e}")))?;
        if overrides.is_empty() {
            return Self::parse(path, source);
        }
        let source = apply_overrides(&source, overrides)?;
        let mut exp = Self::parse(path, source.clone()).map_err(|e| blame_override(e, &source))?;
        exp.overrides = overrides.to_vec();
        Ok(exp)
    }

    /// Parse and validate config text (`path` is used for messages and relative paths).
    pub fn parse(path: &Path, source: String) -> Result<Self, ConfigError> {
        let file: ExperimentFile = toml::from_str(&source).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            ConfigError::at(path, &source, span, e.message().to_string())
        })?;
        check_finite(path, &source)?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let err = |span: Range<usize>, msg: String| ConfigError::at(path, &source, span, msg);

        let (mesh_path, env_path) = scene_files(&file, path, &dir, &err)?;
        let transfer = transfer_of(&file, &err)?;
        check_runtime(&file, path, &err)?;
        let (compressors, methods) = settings_of(&file, &dir, &transfer, &err)?;
        let mut file = file;
        resolve_materials(&mut file, &dir, &err)?;
        Ok(Self {
            config_path: path.to_path_buf(),
            source,
            overrides: vec![],
            file,
            mesh_path,
            env_path,
            transfer,
            compressors,
            methods,
        })
    }

    pub fn name(&self) -> &str {
        self.file.name.get_ref()
    }

    /// The scene's material entries: `[scene.material]`, or `[[scene.materials]]`, or the
    /// default white-ish Lambertian when neither is given.
    pub fn materials(&self) -> Vec<MaterialConfig> {
        let sc = &self.file.scene;
        match (&sc.material, sc.materials.is_empty()) {
            (Some(m), _) => vec![m.get_ref().clone()],
            (None, false) => sc.materials.iter().map(|m| m.get_ref().clone()).collect(),
            (None, true) => vec![MaterialConfig::default()],
        }
    }

    /// Every compressor setting, in config order with sweeps expanded.
    pub fn compressor_settings(&self) -> &[CompressorSetting] {
        &self.compressors
    }

    /// Add a compressor setting made by a program rather than read from the file (a hosted
    /// compressor, `biscale_compressors::hosted`), after the file's: its kind must know it
    /// (the registry's check) and its label must be new and a plain file name.
    pub fn add_compressor(&mut self, setting: CompressorSetting) -> Result<(), ConfigError> {
        let fail = |what: String| {
            Err(ConfigError {
                file: format!("compressor `{}`", setting.label),
                line: 0,
                column: 0,
                message: cut_message(what),
                snippet: String::new(),
            })
        };
        let Some(kind) = biscale_compressors::registry::find(&setting.kind) else {
            return fail(format!("no compressor kind `{}`", setting.kind));
        };
        if let Err(e) = (kind.check)(&setting.params) {
            return fail(e);
        }
        let plain = !setting.label.is_empty()
            && setting.label.len() <= 100
            && setting.label.chars().all(|c| c.is_ascii_alphanumeric() || "-_.+".contains(c))
            && !setting.label.starts_with('.');
        if !plain {
            return fail("a label is 1 to 100 letters, digits and `-_.+`, not starting with `.`".into());
        }
        if let Some(why) = reserved_label(&setting.label) {
            return fail(why);
        }
        let taken = self.compressors.iter().chain(&self.methods).any(|s| s.label == setting.label);
        if taken {
            return fail("this label is taken by another setting of the experiment".into());
        }
        self.compressors.push(setting);
        Ok(())
    }

    /// Every method setting (`[[methods]]`), in config order with sweeps expanded.
    pub fn method_settings(&self) -> &[MethodSetting] {
        &self.methods
    }

    /// The transfer settings: the light basis of `L` and `T`, the local basis of `T`, `L*` and
    /// the BTFs, and the visibility resolution.
    pub fn transfer_settings(&self) -> biscale_core::transfer::TransferSettings {
        self.transfer
    }
}

/// How a config's checks locate an error: a span of the file's text and a message.
type Locate<'a> = dyn Fn(Range<usize>, String) -> ConfigError + 'a;

/// `v` within `lo..=hi`, else an error located at it.
fn in_range(v: &Spanned<u32>, lo: u32, hi: u32, what: &str, err: &Locate<'_>) -> Result<(), ConfigError> {
    if *v.get_ref() < lo || *v.get_ref() > hi {
        return Err(err(v.span(), format!("{what} must be in {lo}..={hi}, got {}", v.get_ref())));
    }
    Ok(())
}

/// The experiment's name, and its mesh and light files resolved against the config's folder.
fn scene_files(
    file: &ExperimentFile,
    path: &Path,
    dir: &Path,
    err: &Locate<'_>,
) -> Result<(PathBuf, Option<PathBuf>), ConfigError> {
    let resolve = |p: &Spanned<PathBuf>, what: &str| -> Result<PathBuf, ConfigError> {
        let full = dir.join(p.get_ref());
        if let Some(problem) = not_a_file(&full) {
            return Err(err(p.span(), format!("{what} file {problem}: {}", full.display())));
        }
        Ok(full)
    };
    // Bidirectional and other invisible format characters (U+202E makes `exe.txt` read as
    // `txt.exe`) are refused with the control characters.
    let format_char = |c: char| matches!(c, '\u{200b}'..='\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2060}'..='\u{2069}' | '\u{061c}' | '\u{feff}');
    if file.name.get_ref().trim().is_empty()
        || file.name.get_ref().contains(['/', '\\'])
        || file.name.get_ref().starts_with('.')
        || file.name.get_ref().chars().any(|c| c.is_control() || format_char(c))
        || file.name.get_ref().chars().count() > MAX_NAME_CHARS
    {
        return Err(err(
            file.name.span(),
            format!(
                "name must be a plain folder name (no slashes, control or invisible format characters, not empty, \
                 at most {MAX_NAME_CHARS} characters)"
            ),
        ));
    }
    // File kinds are checked here, before `run` traces anything (`plan` checks them too).
    let kind_of = |p: &Spanned<PathBuf>, what: &str, allowed: &[&str]| -> Result<(), ConfigError> {
        let ext = p.get_ref().extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if allowed.contains(&ext.as_str()) {
            return Ok(());
        }
        let want: Vec<String> = allowed.iter().map(|a| format!(".{a}")).collect();
        Err(err(p.span(), format!("{what} must be a {} file, got '{}'", want.join(" or "), p.get_ref().display())))
    };
    kind_of(&file.scene.mesh, "scene.mesh", &["obj", "ply"])?;
    if let Some(p) = &file.lighting.env_map {
        kind_of(p, "lighting.env_map", &["exr", "hdr"])?;
    }
    let mesh_path = resolve(&file.scene.mesh, "mesh")?;
    let env_path = match (&file.lighting.env_map, &file.lighting.constant) {
        (Some(p), None) => match biscale_core::sampling::cube_env::face_paths(&dir.join(p.get_ref())) {
            // Six cube faces: each must be there (the pattern itself is no file).
            Some(faces) => {
                for (face, tag) in faces.iter().zip(biscale_core::sampling::cube_env::FACE_TAGS) {
                    if let Some(problem) = not_a_file(face) {
                        return Err(err(p.span(), format!("env map cube face `{tag}` {problem}: {}", face.display())));
                    }
                }
                Some(dir.join(p.get_ref()))
            }
            None => Some(resolve(p, "env map")?),
        },
        (None, Some(c)) => {
            if c.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return Err(ConfigError::whole_file(path, "lighting.constant must be finite and >= 0"));
            }
            None
        }
        (Some(p), Some(_)) => {
            return Err(err(p.span(), "give either lighting.env_map or lighting.constant, not both".into()))
        }
        (None, None) => {
            return Err(ConfigError::whole_file(path, "[lighting] needs env_map = \"...\" or constant = [r, g, b]"))
        }
    };
    if let Some(b) = &file.lighting.sun_boost {
        if !(b.get_ref().is_finite() && *b.get_ref() > 0.0) {
            return Err(err(b.span(), "sun_boost must be a positive finite factor".into()));
        }
    }
    Ok((mesh_path, env_path))
}

/// The transfer table's keys as the bases everything downstream takes them from.
fn transfer_of(
    file: &ExperimentFile,
    err: &Locate<'_>,
) -> Result<biscale_core::transfer::TransferSettings, ConfigError> {
    let t = &file.transfer;
    in_range(&t.cubemap_resolution, 1, 104, "transfer.cubemap_resolution (N = 6 R^2 must fit 16-bit indices)", err)?;
    in_range(&t.visibility_resolution, 1, 1024, "transfer.visibility_resolution", err)?;
    in_range(&t.local_grid, 1, 64, "transfer.local_grid", err)?;
    if !t.visibility_resolution.get_ref().is_multiple_of(*t.cubemap_resolution.get_ref()) {
        return Err(err(
            t.visibility_resolution.span(),
            format!(
                "transfer.visibility_resolution ({}) must be a multiple of cubemap_resolution ({})",
                t.visibility_resolution.get_ref(),
                t.cubemap_resolution.get_ref()
            ),
        ));
    }
    let s = t.visibility_resolution.get_ref() / t.cubemap_resolution.get_ref();
    if s as u64 * s as u64 > u16::MAX as u64 {
        return Err(err(
            t.visibility_resolution.span(),
            format!(
                "transfer.visibility_resolution / cubemap_resolution = {s} gives {} visibility samples per texel, \
                 over {} (counts are 16-bit)",
                s as u64 * s as u64,
                u16::MAX
            ),
        ));
    }
    // The one place the transfer keys become bases: everything downstream (the light
    // vector, T, the BTFs) takes them from these settings.
    biscale_core::transfer::TransferSettings::new(
        *t.cubemap_resolution.get_ref(),
        *t.visibility_resolution.get_ref(),
        *t.local_grid.get_ref(),
    )
    .map(|s| s.with_visibility(t.visibility))
    .map_err(|e| err(t.local_grid.span(), e.to_string()))
}

/// The `[runtime]` and `[report]` values: sizes, counts and the camera.
fn check_runtime(file: &ExperimentFile, path: &Path, err: &Locate<'_>) -> Result<(), ConfigError> {
    in_range(&file.runtime.width, 1, 16384, "runtime.width", err)?;
    in_range(&file.runtime.height, 1, 16384, "runtime.height", err)?;
    if let Some(s) = &file.runtime.samples_per_pixel {
        if let Err(what) = biscale_core::scene::camera::samples_per_axis_of(*s.get_ref()) {
            return Err(err(s.span(), format!("runtime.samples_per_pixel {what}")));
        }
    }
    if let Some(r) = file.runtime.moments_resolve.as_ref().filter(|r| r.get_ref().per_pixel()) {
        let name = r.get_ref().name();
        if !file.runtime.light_moments {
            return Err(err(
                r.span(),
                format!(
                    "runtime.moments_resolve = \"{name}\" resolves light moments: set runtime.light_moments = true"
                ),
            ));
        }
    }
    in_range(&file.report.reference_downscale, 1, 64, "report.reference_downscale", err)?;
    let a = &file.runtime.animation;
    for (frames, key) in [(a.light_frames, "light_frames"), (a.camera_frames, "camera_frames")] {
        if frames > MAX_ANIMATION_FRAMES {
            return Err(ConfigError::whole_file(
                path,
                format!(
                    "runtime.animation.{key} must be at most {MAX_ANIMATION_FRAMES} (0: no animation), got {frames}"
                ),
            ));
        }
    }
    if a.fps == 0 || a.fps > 120 {
        return Err(ConfigError::whole_file(
            path,
            format!("runtime.animation.fps must be in 1..=120 (frames per second), got {}", a.fps),
        ));
    }
    if let Some(inset) = &file.report.inset {
        let [x, y, w, h] = *inset.get_ref();
        let (width, height) = (*file.runtime.width.get_ref(), *file.runtime.height.get_ref());
        if w == 0 || h == 0 || x as u64 + w as u64 > width as u64 || y as u64 + h as u64 > height as u64 {
            return Err(err(
                inset.span(),
                format!(
                    "report.inset = [x, y, width, height] must be a non-empty region inside the {width}x{height} \
                     render (x + width <= {width}, y + height <= {height}), got [{x}, {y}, {w}, {h}]"
                ),
            ));
        }
    }
    if let Some(e) = file.report.error_scale.filter(|e| !(*e > 0.0 && e.is_finite())) {
        return Err(ConfigError::whole_file(path, format!("report.error_scale must be a positive number, got {e}")));
    }
    if let Some(e) = file.report.reference_error_scale.filter(|e| !(*e > 0.0 && e.is_finite())) {
        return Err(ConfigError::whole_file(
            path,
            format!("report.reference_error_scale must be a positive number, got {e}"),
        ));
    }
    if !(file.report.target_error > 0.0 && file.report.target_error.is_finite()) {
        return Err(ConfigError::whole_file(path, "report.target_error must be a positive number"));
    }
    if file.runtime.repeats == 0 || file.runtime.repeats > MAX_REPEATS {
        return Err(ConfigError::whole_file(
            path,
            format!(
                "runtime.repeats must be in 1..={MAX_REPEATS} (timed gathers per setting), got {}",
                file.runtime.repeats
            ),
        ));
    }
    let cam = &file.runtime.camera;
    if !(cam.fov_y_degrees > 0.0 && cam.fov_y_degrees < 180.0) {
        return Err(ConfigError::whole_file(
            path,
            format!("runtime.camera.fov_y_degrees must be in (0, 180), got {}", cam.fov_y_degrees),
        ));
    }
    if !(cam.elevation_degrees > -90.0 && cam.elevation_degrees < 90.0) {
        return Err(ConfigError::whole_file(
            path,
            format!(
                "runtime.camera.elevation_degrees must be in (-90, 90) (at the poles the view has no up), got {}",
                cam.elevation_degrees
            ),
        ));
    }
    if let (Some(p), Some(t)) = (cam.position, cam.target) {
        if p == t {
            return Err(ConfigError::whole_file(
                path,
                format!("runtime.camera.position and target are the same point {p:?}: the camera looks nowhere"),
            ));
        }
    }
    let pixels = *file.runtime.width.get_ref() as u64 * *file.runtime.height.get_ref() as u64;
    if pixels > MAX_PIXELS {
        return Err(err(
            file.runtime.width.span(),
            format!(
                "runtime.width x height = {pixels} pixels is over the limit of {MAX_PIXELS} ({:.1} GB of f32 RGB per \
                 image, one per setting plus the uncompressed one); make the image smaller",
                pixels as f64 * 12.0 / 1e9
            ),
        ));
    }

    Ok(())
}

/// The `[[compressors]]` and `[[methods]]` settings after sweep expansion, each label once,
/// each compressor checked against the transfer shape.
fn settings_of(
    file: &ExperimentFile,
    dir: &Path,
    transfer: &biscale_core::transfer::TransferSettings,
    err: &Locate<'_>,
) -> Result<(Vec<Setting>, Vec<Setting>), ConfigError> {
    // Compressor and method settings share one label space (file names, report rows).
    let (mut compressors, mut methods): (Vec<Setting>, Vec<Setting>) = (vec![], vec![]);
    let mut labels: Vec<String> = vec![];
    for (entries, what, kinds, out) in [
        (&file.compressors, "compressor", compressor_kinds(), &mut compressors),
        (&file.methods, "method", method_kinds(), &mut methods),
    ] {
        for c in entries {
            for setting in expand_settings(c, dir, &err, what, &kinds)? {
                if labels.contains(&setting.label) {
                    return Err(err(
                        c.span(),
                        format!("setting {} appears twice (its images and report rows would collide)", setting.label),
                    ));
                }
                if what == "compressor" {
                    check_against_transfer(&setting, transfer).map_err(|m| err(c.span(), m))?;
                }
                labels.push(setting.label.clone());
                out.push(setting);
            }
        }
    }
    Ok((compressors, methods))
}

/// The materials checked, named once each, their files resolved against the config's folder.
fn resolve_materials(file: &mut ExperimentFile, dir: &Path, err: &Locate<'_>) -> Result<(), ConfigError> {
    if let (Some(_), Some(first)) = (&file.scene.material, file.scene.materials.first()) {
        return Err(err(first.span(), "give either [scene.material] or [[scene.materials]], not both".into()));
    }
    let mut seen_names: Vec<String> = vec![];
    let several = file.scene.materials.len() > 1;
    for m in file.scene.material.iter_mut().chain(file.scene.materials.iter_mut()) {
        let span = m.span();
        check_material(m.get_ref()).map_err(|e| err(span.clone(), format!("material: {e}")))?;
        match m.get_ref().name() {
            Some(n) if seen_names.iter().any(|s| s == n) => {
                return Err(err(span, format!("material name {n:?} is used twice")));
            }
            Some(n) => seen_names.push(n.to_string()),
            None if several => {
                return Err(err(
                    span,
                    "with several [[scene.materials]], each needs a name (its OBJ usemtl or group)".into(),
                ));
            }
            None => {}
        }
        if let MaterialConfig::Bonn(b) = m.get_mut() {
            let full = dir.join(&b.path);
            if !full.is_dir() {
                return Err(err(span.clone(), format!("bonn sample folder not found: {}", full.display())));
            }
            b.path = full;
        }
        if let MaterialConfig::Synthesized(syn) = m.get_mut() {
            for (file_ref, what) in [(&mut syn.height_map, "height_map"), (&mut syn.albedo_map, "albedo_map")] {
                if let Some(p) = file_ref {
                    let full = dir.join(&*p);
                    if let Some(problem) = not_a_file(&full) {
                        return Err(err(span.clone(), format!("{what} file {problem}: {}", full.display())));
                    }
                    *p = full;
                }
            }
        }
    }
    Ok(())
}

/// The comment that marks a line of the effective config as set by `--set KEY=...`.
const SET_MARK: &str = "# --set ";

/// The config text with each `--set KEY=VALUE` applied in order: `KEY` a dotted path of
/// tables (`runtime.light_moments`; a number picks an entry of an array of tables,
/// `compressors.1.terms`), created when missing; `VALUE` a TOML value (`true`, `8`,
/// `[4, 8]` sweeps as in the file, `"text"`), or else taken as a string. Each set line carries
/// a `# --set KEY` comment, so an error the config's checks find there is reported as
/// `--set KEY: ...` ([`blame_override`]). A text the TOML parser refuses is returned as it is,
/// for [`Experiment::parse`] to locate its error.
pub fn apply_overrides(source: &str, overrides: &[String]) -> Result<String, ConfigError> {
    let Ok(mut doc) = source.parse::<toml_edit::DocumentMut>() else {
        return Ok(source.to_string());
    };
    for arg in overrides {
        let (key, value) = arg
            .split_once('=')
            .ok_or_else(|| ConfigError::of_override(arg, "expected KEY=VALUE (a dotted key, then a TOML value)"))?;
        let key = key.trim();
        let segments: Vec<&str> = key.split('.').collect();
        let bare = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
        if !segments.iter().all(|s| bare(s)) {
            return Err(ConfigError::of_override(key, "a key is names of letters, digits, `_` and `-` joined by dots"));
        }
        let value = value.trim();
        let parsed: toml_edit::Value = value.parse().unwrap_or_else(|_| toml_edit::Value::from(value));
        // On one line, so the line an error is found on carries the mark.
        let parsed: toml_edit::Value = one_line(&parsed).parse().expect("one_line writes a TOML value");
        let parsed = parsed.decorated(" ", format!(" {SET_MARK}{key}"));
        let (last, parents) = segments.split_last().expect("split yields at least one segment");
        /// Where the walk down the key stands: in a table, or at a list of tables.
        enum Cursor<'a> {
            Table(&'a mut dyn toml_edit::TableLike),
            List(&'a mut toml_edit::ArrayOfTables),
        }
        let mut cursor = Cursor::Table(doc.as_table_mut());
        for (i, seg) in parents.iter().enumerate() {
            let above = segments[..i].join(".");
            cursor = match cursor {
                Cursor::List(list) => {
                    let n = list.len();
                    let index: usize = seg.parse().map_err(|_| {
                        ConfigError::of_override(key, format!("`{above}` is a list of tables: index it by number"))
                    })?;
                    let t = list.get_mut(index).ok_or_else(|| {
                        ConfigError::of_override(
                            key,
                            format!("`{above}` has {n} entries, numbered 0 to {}", n.saturating_sub(1)),
                        )
                    })?;
                    Cursor::Table(t)
                }
                Cursor::Table(t) => {
                    if t.get(seg).is_none() {
                        // A table `--set` makes carries the mark on its header line, where an
                        // error about its name is found.
                        let mut new = toml_edit::Table::new();
                        new.decor_mut().set_suffix(format!(" {SET_MARK}{key}"));
                        t.insert(seg, toml_edit::Item::Table(new));
                    }
                    match t.get_mut(seg).expect("inserted above") {
                        toml_edit::Item::ArrayOfTables(list) => Cursor::List(list),
                        other => Cursor::Table(other.as_table_like_mut().ok_or_else(|| {
                            ConfigError::of_override(
                                key,
                                format!("`{}` is a value, not a table", segments[..=i].join(".")),
                            )
                        })?),
                    }
                }
            };
        }
        match cursor {
            // An existing key keeps its own decor (the comments above it); only its value changes.
            Cursor::Table(table) => match table.get_mut(last) {
                Some(item) => *item = toml_edit::Item::Value(parsed),
                None => {
                    table.insert(last, toml_edit::Item::Value(parsed));
                }
            },
            Cursor::List(_) => {
                return Err(ConfigError::of_override(
                    key,
                    format!(
                        "`{}` is a list of tables: set a key of one entry (`{}.0.KEY`)",
                        parents.join("."),
                        parents.join(".")
                    ),
                ))
            }
        }
    }
    Ok(doc.to_string())
}

/// An error located on a line that `--set KEY` wrote (in `source`, the text with the
/// overrides) becomes `--set KEY: message`.
fn blame_override(e: ConfigError, source: &str) -> ConfigError {
    let line = e.line.checked_sub(1).and_then(|n| source.lines().nth(n)).unwrap_or("");
    match line.rfind(SET_MARK) {
        Some(at) => ConfigError::of_override(line[at + SET_MARK.len()..].trim(), e.message),
        None => e,
    }
}

/// `v` as TOML text on one line: strings as basic strings with escapes (a newline as `\n`),
/// arrays and inline tables with their items so, other values as written.
fn one_line(v: &toml_edit::Value) -> String {
    use std::fmt::Write as _;
    use toml_edit::Value;
    match v {
        Value::String(s) => {
            let mut out = String::from("\"");
            for c in s.value().chars() {
                match c {
                    '"' => out.push_str("\\\""),
                    '\\' => out.push_str("\\\\"),
                    '\n' => out.push_str("\\n"),
                    '\t' => out.push_str("\\t"),
                    '\r' => out.push_str("\\r"),
                    c if c.is_control() => {
                        let _ = write!(out, "\\u{:04X}", c as u32);
                    }
                    c => out.push(c),
                }
            }
            out.push('"');
            out
        }
        Value::Array(a) => format!("[{}]", a.iter().map(one_line).collect::<Vec<_>>().join(", ")),
        Value::InlineTable(t) => {
            let items: Vec<String> =
                t.iter().map(|(k, v)| format!("{} = {}", toml_edit::Key::new(k).display_repr(), one_line(v))).collect();
            format!("{{ {} }}", items.join(", "))
        }
        Value::Integer(f) => f.display_repr().into_owned(),
        Value::Float(f) => f.display_repr().into_owned(),
        Value::Boolean(f) => f.display_repr().into_owned(),
        Value::Datetime(f) => f.display_repr().into_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--set` edits the file's own text: comments and layout stay, a value is replaced or
    /// added (its tables made), a list of tables is indexed by number, and each set line is
    /// marked with its key.
    #[test]
    fn overrides_edit_the_text_in_place() {
        let source =
            "# my notes\nname = \"x\"\n[transfer]\nlocal_grid = 8\n\n[[compressors]]\nkind = \"haar\"\nterms = [4, 8]\n";
        let sets = ["transfer.local_grid=4", "runtime.light_moments=true", "compressors.0.terms=[12]", "name=y"]
            .map(String::from);
        let out = apply_overrides(source, &sets).unwrap();
        let v: toml::Value = toml::from_str(&out).unwrap();
        assert_eq!(v["transfer"]["local_grid"].as_integer(), Some(4));
        assert_eq!(v["runtime"]["light_moments"].as_bool(), Some(true));
        assert_eq!(v["compressors"][0]["terms"].as_array().unwrap().len(), 1);
        assert_eq!(v["name"].as_str(), Some("y"), "a value TOML does not parse is taken as a string");
        assert!(out.contains("# my notes\n") && out.contains("local_grid = 4 # --set transfer.local_grid"), "{out}");
        assert_eq!(apply_overrides(source, &[]).unwrap(), source, "no override, the text as it was");
    }

    fn parse(s: &str) -> Result<Experiment, ConfigError> {
        // Paths resolve against the workspace root's configs folder.
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/test.toml");
        Experiment::parse(&p, s.to_string())
    }

    const OK: &str = "name = \"t\"\n[scene]\nmesh = \"../assets/meshes/bunny.obj\"\n[lighting]\nconstant = [1, 1, 1]\n";

    /// Issue class "--set of a value with a newline": `--set name=$'x\ny'` became the name of
    /// the output folder and of every report, with a newline in it.
    #[test]
    fn an_experiment_name_with_a_control_character_is_refused() {
        let set = ["name=x\ny".to_string()];
        let text = apply_overrides(OK, &set).unwrap();
        let e = parse(&text).unwrap_err();
        assert!(e.message.contains("plain folder name") && e.message.contains("control"), "{e}");
        // TOML escapes: a tab, DEL, a carriage return.
        for name in [r#""a\tb""#, r#""a\u007Fb""#, r#""a\rb""#] {
            let e = parse(&OK.replace("\"t\"", name)).unwrap_err();
            assert!(e.message.contains("plain folder name"), "{name}: {e}");
        }
        assert!(parse(&OK.replace("\"t\"", "\"bunny-é_1.5\"")).is_ok());
    }

    /// Issue class "a `--set` error located on a config line": a value with a newline, a set
    /// that makes a table, and a long value are all reported as `--set KEY`, not as a line of
    /// the file the user never wrote.
    #[test]
    fn set_errors_name_the_set_even_where_it_spans_lines_or_makes_a_table() {
        let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/smoke.toml");
        let cases = [
            ("name=x\ny", "--set name"),
            ("nonexistent.key=1", "--set nonexistent.key"),
            ("a.b.c=1", "--set a.b.c"),
            ("transfer.nonexistent=1", "--set transfer.nonexistent"),
            ("transfer.local_grid=\"\"\"4\n5\"\"\"", "--set transfer.local_grid"),
            ("transfer.local_grid=[1,\n2]", "--set transfer.local_grid"),
        ];
        for (set, want) in cases {
            let e = Experiment::load_with(&smoke, &[set.to_string()]).unwrap_err();
            assert_eq!((e.file.as_str(), e.line), (want, 0), "{set:?}: {e}");
        }
        let long = format!("transfer.local_grid={}", "x".repeat(100_000));
        let e = Experiment::load_with(&smoke, &[long]).unwrap_err();
        assert_eq!(e.file, "--set transfer.local_grid", "{e}");
        assert!(e.to_string().len() < 2_000, "{}", e.to_string().len());
        // The values themselves survive the one-line rewrite.
        let text =
            apply_overrides(OK, &["name=\"q\\\"uote\\ttab\"".into(), "x.y={ a = [1, \"b\\n\"] }".into()]).unwrap();
        let v: toml::Value = toml::from_str(&text).unwrap();
        assert_eq!(v["name"].as_str(), Some("q\"uote\ttab"));
        assert_eq!(v["x"]["y"]["a"][1].as_str(), Some("b\n"));
        assert_eq!(text.lines().filter(|l| l.contains(SET_MARK)).count(), 3, "{text}");
    }

    /// A 50 MB line made a 50 MB error message: the snippet is a window around the error and
    /// the message is cut in the middle, while short lines are shown whole.
    #[test]
    fn late_validation_snippets_are_cut_to_a_sane_width() {
        let long = "x".repeat(5_000_000);
        let e = parse(&format!("{OK}bogus = \"{long}\"\n")).unwrap_err().to_string();
        assert!(e.len() < 2_000, "{} bytes", e.len());
        assert!(e.contains("test.toml:6:1") && e.contains("unknown field `bogus`") && e.contains("..."), "{e}");
        // The caret still points at the key.
        assert!(e.lines().any(|l| l.trim_start().starts_with("| ^^^^^")), "{e}");
        // A value far into a long line: the window follows it, the caret under it.
        let e = parse(&format!("{OK}[runtime]\nwidth = {{ {} = 1, w = \"x\" }}\n", "a".repeat(300))).unwrap_err();
        let text = e.to_string();
        assert!(text.len() < 2_000, "{text}");
        let lines: Vec<&str> = text.lines().collect();
        let (code, marks) = (lines[lines.len() - 2], lines[lines.len() - 1]);
        let caret = marks.find('^').unwrap();
        assert!(caret < code.len(), "{text}");
        // Long messages lose their middle, short ones nothing.
        let m = cut_message("y".repeat(10_000));
        assert!(m.len() < 500 && m.contains("characters cut"), "{m}");
        assert_eq!(cut_message("short".into()), "short");
    }

    /// `components = 6145` with N = 384 was clamped while metrics reported 6145; Haar terms
    /// above N were accepted. Both are errors at load now, located at their entry.
    #[test]
    fn unbounded_requests_above_the_transfer_shape_are_errors_at_load() {
        let t = "[transfer]\ncubemap_resolution = 8\nvisibility_resolution = 16\nlocal_grid = 4\n";
        let e =
            parse(&format!("{OK}{t}[[compressors]]\nkind = \"cpca\"\nclusters = 4\ncomponents = 385\n")).unwrap_err();
        assert!(e.to_string().contains("components = 385") && e.to_string().contains("384"), "{e}");
        assert_eq!(e.line, 10, "{e}");
        parse(&format!("{OK}{t}[[compressors]]\nkind = \"cpca\"\nclusters = 4\ncomponents = 384\n")).unwrap();
        // A vertex unit holds M N values.
        parse(&format!("{OK}{t}[[compressors]]\nkind = \"cpca\"\nunit = \"vertex\"\ncomponents = 385\n")).unwrap();
        let e = parse(&format!("{OK}{t}[[compressors]]\nkind = \"haar\"\nterms = [12, 385]\n")).unwrap_err();
        assert!(e.to_string().contains("haar-t385") && e.to_string().contains("384 coefficients"), "{e}");
        parse(&format!("{OK}{t}[[compressors]]\nkind = \"haar\"\nterms = 384\n")).unwrap();
    }

    #[test]
    fn an_inset_region_must_lie_inside_the_render_and_errors_name_its_line() {
        let exp =
            parse(&format!("{OK}[runtime]\nwidth = 96\nheight = 72\n[report]\ninset = [10, 20, 30, 40]\n")).unwrap();
        assert_eq!(exp.file.report.inset.as_ref().map(|i| *i.get_ref()), Some([10, 20, 30, 40]));
        assert!(parse(OK).unwrap().file.report.inset.is_none());
        for (inset, what) in [
            ("[70, 0, 30, 10]", "inside the 96x72 render"),
            ("[0, 40, 10, 33]", "got [0, 40, 10, 33]"),
            ("[0, 0, 0, 10]", "non-empty"),
            ("[4294967295, 0, 2, 2]", "inside"),
        ] {
            let text =
                format!("{OK}[runtime]\nwidth = 96\nheight = 72\n[report]\n# the zoomed region\ninset = {inset}\n");
            let e = parse(&text).unwrap_err();
            assert!(e.message.contains(what) && e.message.contains("report.inset"), "{e}");
            assert_eq!(e.line, text.lines().position(|l| l.starts_with("inset")).unwrap() + 1, "{e}");
        }
        // Wrong shapes and types are serde's errors, at the key's line too.
        for inset in ["[1, 2, 3]", "[1, 2, 3, -4]", "\"middle\""] {
            let text = format!("{OK}[report]\ninset = {inset}\n");
            let e = parse(&text).unwrap_err();
            assert_eq!(e.line, text.lines().count(), "{inset}: {e}");
        }
    }

    #[test]
    fn a_fixed_error_scale_must_be_positive_and_light_moments_parse() {
        let e = parse(&format!("{OK}[report]\nerror_scale = -1.0\n")).unwrap_err().to_string();
        assert!(e.contains("report.error_scale must be a positive number, got -1"), "{e}");
        let e = parse(&format!("{OK}[report]\nreference_error_scale = 0.0\n")).unwrap_err().to_string();
        assert!(e.contains("report.reference_error_scale must be a positive number, got 0"), "{e}");
        let exp = parse(&format!("{OK}[report]\nerror_scale = 0.05\n[runtime]\nlight_moments = true\n")).unwrap();
        assert_eq!(exp.file.report.error_scale, Some(0.05));
        assert!(exp.file.runtime.light_moments);
        assert!(!parse(OK).unwrap().file.runtime.light_moments, "the paper's cosine is the default");
    }

    #[test]
    fn the_visibility_method_is_a_transfer_setting() {
        use biscale_core::transfer::Visibility;
        let how = |extra: &str| parse(&format!("{OK}[transfer]\n{extra}")).map(|e| e.transfer_settings().visibility());
        assert_eq!(how("").unwrap(), Visibility::Coverage, "the default");
        assert_eq!(how("visibility = \"rays\"\n").unwrap(), Visibility::Rays);
        assert_eq!(how("visibility = \"coverage\"\nlocal_grid = 4\n").unwrap(), Visibility::Coverage);
        let e = how("visibility = \"raster\"\n").unwrap_err().to_string();
        assert!(e.contains(":7:14") && e.contains("coverage") && e.contains("rays"), "{e}");
    }

    #[test]
    fn a_per_pixel_resolve_needs_moments_on_either_backend() {
        let rt = |extra: &str| parse(&format!("{OK}[runtime]\n{extra}")).map(|e| e.file.runtime.resolve_per_pixel());
        assert!(rt("light_moments = true\nmoments_resolve = \"pixel\"\n").unwrap());
        assert!(!rt("light_moments = true\nmoments_resolve = \"vertex\"\n").unwrap());
        assert!(!rt("light_moments = true\n").unwrap());
        let e = rt("moments_resolve = \"pixel\"\n").unwrap_err().to_string();
        assert!(e.contains(":7:19: runtime.moments_resolve = \"pixel\" resolves light moments"), "{e}");
        // The GPU backend resolves per pixel as the CPU does.
        assert!(rt("light_moments = true\nbackend = \"gpu\"\nmoments_resolve = \"pixel\"\n").unwrap());
        assert!(rt("light_moments = true\nmoments_resolve = \"texel\"\n").is_err());
        // The analytic resolve is a per-pixel one, with the same requirements.
        let runtime = |extra: &str| parse(&format!("{OK}[runtime]\n{extra}")).map(|e| e.file.runtime);
        let r = runtime("light_moments = true\nmoments_resolve = \"pixel_analytic\"\n").unwrap();
        assert!(r.resolve_per_pixel() && r.resolve_analytic());
        assert_eq!(r.moments_resolve(), Some(MomentsResolve::PixelAnalytic));
        let r = runtime("light_moments = true\nmoments_resolve = \"pixel\"\n").unwrap();
        assert!(!r.resolve_analytic() && r.moments_resolve() == Some(MomentsResolve::Pixel));
        assert_eq!(runtime("light_moments = true\n").unwrap().moments_resolve(), Some(MomentsResolve::Vertex));
        assert_eq!(runtime("").unwrap().moments_resolve(), None);
        let e = rt("moments_resolve = \"pixel_analytic\"\n").unwrap_err().to_string();
        assert!(e.contains(":7:19: runtime.moments_resolve = \"pixel_analytic\" resolves light moments"), "{e}");
        assert!(rt("light_moments = true\nbackend = \"gpu\"\nmoments_resolve = \"pixel_analytic\"\n").unwrap());
    }

    #[test]
    fn animations_are_off_by_default_and_their_counts_are_bounded() {
        let a = parse(OK).unwrap().file.runtime.animation;
        assert!(!a.any() && a.settings.is_empty() && a.fps == 12);
        let exp = parse(&format!("{OK}[runtime.animation]\nlight_frames = 24\nsettings = [\"bicluster\"]\n")).unwrap();
        let a = &exp.file.runtime.animation;
        assert!(a.any() && a.light_frames == 24 && a.camera_frames == 0 && a.settings == ["bicluster"]);
        let e = parse(&format!("{OK}[runtime.animation]\ncamera_frames = 721\n")).unwrap_err().to_string();
        assert!(e.contains("runtime.animation.camera_frames must be at most 720"), "{e}");
        let e = parse(&format!("{OK}[runtime.animation]\nfps = 0\n")).unwrap_err().to_string();
        assert!(e.contains("runtime.animation.fps must be in 1..=120"), "{e}");
        assert!(parse(&format!("{OK}[runtime.animation]\nframes = 3\n")).is_err(), "unknown keys are refused");
    }

    #[test]
    fn samples_per_pixel_must_be_a_square() {
        let e = parse(&format!("{OK}[runtime]\nsamples_per_pixel = 8\n")).unwrap_err();
        assert!(
            e.to_string()
                .contains("runtime.samples_per_pixel must be a square (1, 4, 9, 16, ...) of at most 256, got 8"),
            "{e}"
        );
        assert_eq!(e.line, 7, "{e}");
        assert!(parse(&format!("{OK}[runtime]\nsamples_per_pixel = 0\n")).is_err());
        assert!(parse(&format!("{OK}[runtime]\nsamples_per_pixel = 1024\n")).is_err());
        // The default: 4 rays per pixel on either backend.
        assert_eq!(parse(OK).unwrap().file.runtime.samples_per_pixel(), 4);
        let gpu = parse(&format!("{OK}[runtime]\nbackend = \"gpu\"\n")).unwrap();
        assert_eq!(gpu.file.runtime.samples_per_pixel(), 4);
        assert_eq!(
            parse(&format!("{OK}[runtime]\nsamples_per_pixel = 9\n")).unwrap().file.runtime.samples_per_pixel(),
            9
        );
    }

    #[test]
    fn every_bundled_config_loads() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            if e.path().extension().is_some_and(|x| x == "toml") {
                Experiment::load(&e.path()).unwrap_or_else(|err| panic!("{}: {err}", e.path().display()));
                n += 1;
            }
        }
        assert!(n >= 9, "{n} configs");
    }

    #[test]
    fn lpca_representation_keys_are_read_and_checked() {
        let body = |r: &str| {
            format!(
                "{OK}[scene.material]\nkind = \"phong\"\nkd = [0.5, 0.5, 0.5]\nks = [0.1, 0.1, 0.1]\nexponent = 10.0\nrepresentation = {r}\n"
            )
        };
        let e = parse(&body("{ kind = \"lpca\", clusters = 8, unit = \"view\" }")).unwrap();
        let r = e.materials()[0].representation();
        assert_eq!(
            r,
            RepresentationSetting::Lpca(LpcaSettings {
                clusters: 8,
                components: 4,
                unit: LpcaUnit::View,
                quantize: LpcaQuantize::F32,
                iterations: 6
            })
        );
        let e = parse(&body("{ kind = \"lpca\", quantize = \"u8\" }")).unwrap();
        assert_eq!(e.materials()[0].representation().label(), "lpca-k16-c4-u8");
        assert_eq!(r.label(), "lpca-k8-c4-view");
        let e = parse(&body("{ kind = \"lpca\", components = 0 }")).unwrap_err();
        assert!(e.message.contains("components must be at least 1"), "{e}");
        let e = parse(&body("{ kind = \"lpca\", cluster = 3 }")).unwrap_err();
        assert!(e.message.contains("unknown field `cluster`"), "{e}");
    }

    #[test]
    fn a_representation_list_sweeps_and_its_first_is_the_materials_own() {
        let body = |r: &str| {
            format!("{OK}[scene.material]\nkind = \"lambertian\"\nalbedo = [0.5, 0.5, 0.5]\nrepresentation = {r}\n")
        };
        let e = parse(&body("[{ kind = \"lpca\", clusters = 2 }, { kind = \"dense\" }]")).unwrap();
        let m = &e.materials()[0];
        let labels: Vec<String> = m.representations().all().iter().map(|r| r.label()).collect();
        assert_eq!(labels, ["lpca-k2-c4", "dense"]);
        assert_eq!(m.representation().label(), "lpca-k2-c4");
        let e = parse(&body("[]")).unwrap_err();
        assert!(e.message.contains("non-empty array"), "{e}");
        let e = parse(&body("[{ kind = \"dense\" }, { kind = \"dense\" }]")).unwrap_err();
        assert!(e.message.contains("representation dense is listed twice"), "{e}");
        // An entry of the list keeps serde's own message.
        let e = parse(&body("[{ kind = \"lpca\", cluster = 3 }]")).unwrap_err();
        assert!(e.message.contains("unknown field `cluster`"), "{e}");
    }

    #[test]
    fn exposure_is_stops_or_auto() {
        let at = |v: &str| parse(&format!("{OK}[report]\nexposure = {v}\n")).map(|e| e.file.report.exposure);
        assert_eq!(at("-1.5").unwrap(), Exposure::Stops(-1.5));
        assert_eq!(at("2").unwrap(), Exposure::Stops(2.0));
        assert_eq!(at("\"auto\"").unwrap(), Exposure::Auto);
        assert_eq!(parse(OK).unwrap().file.report.exposure, Exposure::Stops(0.0));
        let e = at("\"bright\"").unwrap_err();
        assert!(e.message.contains("a number of stops or \"auto\"") && e.message.contains("bright"), "{e}");
        assert_eq!(e.line, 7, "{e}");
        // Auto takes the 99th percentile of the masked pixels' largest channel to white.
        let img = biscale_core::scene::HdrImage { width: 2, height: 1, pixels: vec![[4.0; 3], [100.0; 3]] };
        assert_eq!(Exposure::Auto.resolve(&img, &[true, false]), -2.0);
        assert_eq!(Exposure::Stops(0.5).resolve(&img, &[true, false]), 0.5);
    }

    #[test]
    fn nan_or_inf_anywhere_is_refused_at_its_literal() {
        // Regression (hostile input): `rotation_degrees = nan` gave NaN images with exit 0,
        // `exposure = inf` an all-white PNG.
        for (text, key, line) in [
            (format!("{OK}[transfer]\nlocal_grid = 8\n"), "", 0),
            (OK.replace("[lighting]", "[lighting]\nrotation_degrees = nan"), "lighting.rotation_degrees = NaN", 5),
            (OK.replace("[lighting]", "[lighting] # inf in a comment\nrotation_degrees = -inf"), "= -inf", 5),
            (format!("{OK}[report]\nexposure = +inf\n"), "report.exposure = inf", 7),
            (format!("{OK}[runtime.camera]\ntarget = [0.0, nan, 0.0]\n"), "runtime.camera.target[1]", 7),
        ] {
            match parse(&text) {
                Ok(_) => assert!(key.is_empty(), "accepted: {text}"),
                Err(e) => {
                    assert!(!key.is_empty(), "{e}");
                    assert!(e.message.contains(key) && e.message.contains("finite"), "{e}");
                    assert_eq!(e.line, line, "{e}");
                }
            }
        }
        // A string that says nan is not a number.
        assert!(first_non_finite("name = \"nan\" # inf\nx = 'inf'\n").is_none());
        assert_eq!(first_non_finite("a = [1.0, -nan]").and_then(|f| f.2), Some(10..14));
    }

    #[test]
    fn non_ascii_strings_before_a_nan_give_its_location_not_a_panic() {
        // Regression (fuzzing): the scan for the literal sliced the text inside a multi-byte
        // character of a string ("byte index is not a char boundary").
        let text = format!("name = \"Нн\\\"ё\" # Ж\n{}", &OK[OK.find('\n').unwrap() + 1..])
            .replace("[lighting]", "[lighting]\nrotation_degrees = nan");
        let e = parse(&text).unwrap_err();
        assert!(e.message.contains("lighting.rotation_degrees = NaN"), "{e}");
        assert_eq!((e.line, e.column), (5, 20), "{e}");
        for s in ["\"Нн\" = nan", "x = \'\'\'ё\'\'\'\ny = inf", "\"\\Ж\" = -inf", "\"\\\\Ж\" = -inf", "x = \"ё"] {
            // Text that is not TOML has no values (its parse error is reported first).
            let want = toml_edit::ImDocument::parse(s)
                .ok()
                .and_then(|_| s.find("nan").or_else(|| s.find("-inf")).or_else(|| s.find("inf")));
            assert_eq!(first_non_finite(s).and_then(|f| f.2).map(|r| r.start), want, "{s}");
        }
    }

    #[test]
    fn camera_and_file_kinds_that_run_would_reject_fail_at_load() {
        // Regression (late validation): `plan` accepted these and `run` failed minutes in.
        for (extra, want) in [
            ("[runtime.camera]\nfov_y_degrees = 0.0\n", "fov_y_degrees must be in (0, 180)"),
            ("[runtime.camera]\nfov_y_degrees = 180.0\n", "fov_y_degrees must be in (0, 180)"),
            ("[runtime.camera]\nelevation_degrees = 90.0\n", "elevation_degrees must be in (-90, 90)"),
            ("[runtime.camera]\nposition = [1.0, 2.0, 3.0]\ntarget = [1.0, 2.0, 3.0]\n", "the same point"),
        ] {
            let e = parse(&format!("{OK}{extra}")).unwrap_err();
            assert!(e.message.contains(want), "{extra}: {e}");
        }
        let e = parse(&OK.replace("bunny.obj", "bunny.stl")).unwrap_err();
        assert!(e.message.contains("scene.mesh must be a .obj or .ply file") && e.line == 3, "{e}");
        let e = parse(&OK.replace("constant = [1, 1, 1]", "env_map = \"sky.png\"")).unwrap_err();
        assert!(e.message.contains("lighting.env_map must be a .exr or .hdr file"), "{e}");
    }

    #[test]
    fn a_sweep_of_too_many_settings_is_refused_before_expanding() {
        let list = |n: usize| format!("[{}]", (1..=n).map(|i| i.to_string()).collect::<Vec<_>>().join(", "));
        let big =
            format!("{OK}[[compressors]]\nkind = \"cpca\"\nclusters = {}\ncomponents = {}\n", list(3000), list(3000));
        let e = parse(&big).unwrap_err();
        assert!(e.message.contains("9000000 settings") && e.message.contains("1000"), "{e}");
        assert_eq!(e.line, 6, "{e}");
    }

    #[test]
    fn too_much_supersampling_points_at_visibility_resolution() {
        let e = parse(&format!("{OK}[transfer]\ncubemap_resolution = 4\nvisibility_resolution = 1024\n")).unwrap_err();
        assert!(e.message.contains("= 256") && e.message.contains("65536"), "{e}");
        assert_eq!(e.line, 8, "{e}");
    }

    #[test]
    fn unbounded_repeats_and_images_are_refused_with_the_limit() {
        let e = parse(&format!("{OK}[runtime]\nrepeats = 1000000000000000000\n")).unwrap_err();
        assert!(e.message.contains("runtime.repeats") && e.message.contains("10000"), "{e}");
        let e = parse(&format!("{OK}[runtime]\nwidth = 16384\nheight = 16384\n")).unwrap_err();
        assert!(e.message.contains("pixels") && e.message.contains("GB"), "{e}");
        assert_eq!(e.line, 7, "{e}");
        parse(&format!("{OK}[runtime]\nwidth = 8192\nheight = 8192\nrepeats = 10000\n")).unwrap();
    }

    #[test]
    fn minimal_config_parses_with_defaults() {
        let e = parse(OK).unwrap();
        assert_eq!(e.transfer_settings(), biscale_core::transfer::TransferSettings::default());
        assert_eq!(*e.file.runtime.width.get_ref(), 640);
    }

    #[test]
    fn unknown_key_names_line_and_column() {
        let e = parse(&format!("{OK}[transfer]\nlocal_grd = 8\n")).unwrap_err();
        assert_eq!((e.line, e.column), (7, 1), "{e}");
        assert!(e.message.contains("unknown field `local_grd`"), "{e}");
        assert!(e.to_string().contains("test.toml:7:1"), "{e}");
    }

    #[test]
    fn wrong_type_and_range_are_located() {
        let e = parse(&format!("{OK}[transfer]\nlocal_grid = \"8\"\n")).unwrap_err();
        assert_eq!(e.line, 7, "{e}");
        let e = parse(&format!("{OK}[transfer]\nlocal_grid = 0\n")).unwrap_err();
        assert_eq!((e.line, e.column), (7, 14), "{e}");
        assert!(e.message.contains("1..=64"), "{e}");
        let e = parse(&format!("{OK}[transfer]\ncubemap_resolution = 32\nvisibility_resolution = 48\n")).unwrap_err();
        assert_eq!(e.line, 8, "{e}");
        assert!(e.message.contains("multiple"), "{e}");
    }

    #[test]
    fn ply_meshes_and_six_face_env_maps_are_accepted() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.ply"), "ply\n").unwrap();
        for tag in biscale_core::sampling::cube_env::FACE_TAGS {
            std::fs::write(dir.path().join(format!("sky_{tag}.exr")), "").unwrap();
        }
        let text = "name = \"t\"\n[scene]\nmesh = \"m.ply\"\n[lighting]\nenv_map = \"sky_{face}.exr\"\n";
        let exp = Experiment::parse(&dir.path().join("x.toml"), text.into()).unwrap();
        assert_eq!(exp.mesh_path, dir.path().join("m.ply"));
        assert_eq!(exp.env_path, Some(dir.path().join("sky_{face}.exr")));
        // A missing face is named, at the key.
        std::fs::remove_file(dir.path().join("sky_pz.exr")).unwrap();
        let e = Experiment::parse(&dir.path().join("x.toml"), text.into()).unwrap_err();
        assert_eq!((e.line, e.column), (5, 11), "{e}");
        assert!(e.message.contains("env map cube face `pz` not found") && e.message.contains("sky_pz.exr"), "{e}");
    }

    #[test]
    fn missing_mesh_is_located() {
        let e = parse(&OK.replace("bunny.obj", "nope.obj")).unwrap_err();
        assert_eq!((e.line, e.column), (3, 8), "{e}");
        assert!(e.message.contains("mesh file not found"), "{e}");
    }

    #[test]
    fn malformed_toml_is_located() {
        let e = parse("name = \"t\"\n[scene\nmesh = 3\n").unwrap_err();
        assert_eq!(e.line, 2, "{e}");
    }

    #[test]
    fn compressor_sweeps_and_bad_kinds() {
        let e =
            parse(&format!("{OK}[[compressors]]\nkind = \"cpca\"\nclusters = [8, 16]\ncomponents = [2, 4]\n")).unwrap();
        let labels: Vec<&str> = e.compressor_settings().iter().map(|s| s.label.as_str()).collect();
        assert_eq!(labels, ["cpca-k8-c2", "cpca-k8-c4", "cpca-k16-c2", "cpca-k16-c4"]);
        assert_eq!(e.compressor_settings()[1].params, serde_json::json!({ "clusters": 8, "components": 4 }));
        let e = parse(&format!("{OK}[[compressors]]\nkind = \"zip\"\n")).unwrap_err();
        assert_eq!((e.line, e.column), (7, 8), "{e}");
        assert!(e.message.contains("unknown compressor kind \"zip\""), "{e}");
        let e = parse(&format!("{OK}[[compressors]]\nkind = \"haar\"\nterms = 0\n")).unwrap_err();
        assert!(e.message.contains("terms must be at least 1"), "{e}");
        assert_eq!((e.line, e.column), (8, 9), "{e}");
        let e = parse(&format!("{OK}[[compressors]]\nkind = \"haar\"\nterms = []\n")).unwrap_err();
        assert!(e.message.contains("at least one value"), "{e}");
        // The compressor's own keys are checked by its parameter type, at the key.
        let e = parse(&format!("{OK}[[compressors]]\nkind = \"cpca\"\nclustrs = 8\n")).unwrap_err();
        assert!(e.message.contains("unknown field `clustrs`"), "{e}");
        assert_eq!((e.line, e.column), (8, 1), "{e}");
        let e = parse(&format!("{OK}[[compressors]]\nkind = \"cpca\"\nclusters = \"8\"\n")).unwrap_err();
        assert!(e.message.contains("invalid type"), "{e}");
        assert_eq!((e.line, e.column), (8, 12), "{e}");
        // The same setting twice would overwrite its own images.
        let twice = format!(
            "{OK}[[compressors]]\nkind = \"haar\"\nterms = [4, 8]\n[[compressors]]\nkind = \"haar\"\nterms = 8\n"
        );
        assert!(parse(&twice).unwrap_err().message.contains("haar-t8 appears twice"));
    }

    #[test]
    fn method_settings_sweep_and_are_checked_where_they_are_written() {
        let e = parse(&format!("{OK}[[methods]]\nkind = \"sh\"\norder = [3, 5]\nbounces = 1\n")).unwrap();
        let labels: Vec<&str> = e.method_settings().iter().map(|s| s.label.as_str()).collect();
        assert_eq!(labels, ["sh-n3-b1", "sh-n5-b1"]);
        assert_eq!(e.method_settings()[0].params, serde_json::json!({ "order": 3, "bounces": 1 }));
        let e = parse(&format!(
            "{OK}[[methods]]\nkind = \"sh\"\norder = 5\ncompressor = {{ kind = \"cpca\", clusters = 8, unit = \"vertex\" }}\n"
        ))
        .unwrap();
        assert_eq!(e.method_settings()[0].label, "sh-n5-cpca-k8-c8-vertex");
        let bad = |body: &str| parse(&format!("{OK}[[methods]]\n{body}")).unwrap_err();
        let e = bad("kind = \"wavelet\"\n");
        assert!(e.message.contains("unknown method kind \"wavelet\"") && e.message.contains("`sh`"), "{e}");
        assert_eq!((e.line, e.column), (7, 8), "{e}");
        let e = bad("kind = \"sh\"\norder = 9\n");
        assert!(e.message.contains("order must be 2..=8"), "{e}");
        assert_eq!((e.line, e.column), (8, 9), "{e}");
        let e = bad("kind = \"sh\"\norder = 5\nrays = 0\n");
        assert!(e.message.contains("rays per vertex"), "{e}");
        let e = bad("kind = \"sh\"\norder = 5\nbounce = 1\n");
        assert!(e.message.contains("unknown field `bounce`"), "{e}");
        assert_eq!((e.line, e.column), (9, 1), "{e}");
        let e = bad("kind = \"sh\"\norder = 5\ncompressor = { kind = \"zip\" }\n");
        assert!(e.message.contains("unknown compressor kind `zip`"), "{e}");
        let e = bad("kind = \"sh\"\norder = 5\ncompressor = { kind = \"plugin\" }\n");
        assert!(e.message.contains("a plugin cannot compress"), "{e}");
        let e = bad("kind = \"sh\"\norder = 5\ncompressor = { kind = \"cpca\", clustrs = 2 }\n");
        assert!(e.message.contains("unknown field `clustrs`"), "{e}");
        let e = bad("order = 5\n");
        assert!(e.message.contains("a method needs kind"), "{e}");
        // Method and compressor labels share one space (file names and report rows).
        let twice = format!("{OK}[[methods]]\nkind = \"sh\"\norder = [5, 5]\n");
        assert!(parse(&twice).unwrap_err().message.contains("sh-n5 appears twice"));
    }

    #[test]
    fn plugin_entries_resolve_their_library() {
        let e = parse(&format!(
            "{OK}[[compressors]]\nkind = \"plugin\"\npath = \"nope.so\"\nparams = {{ scale = 0.25 }}\n"
        ))
        .unwrap_err();
        assert_eq!((e.line, e.column), (8, 8), "{e}");
        assert!(e.message.contains("plugin library not found"), "{e}");
        let e = parse(&format!(
            "{OK}[[compressors]]\nkind = \"plugin\"\npath = \"bunny.toml\"\nparams = {{ scale = 0.25 }}\n"
        ))
        .unwrap();
        let s = &e.compressor_settings()[0];
        assert_eq!(s.label, "plugin-bunny");
        let path = Path::new(s.params["path"].as_str().unwrap());
        assert!(path.is_absolute() && path.is_file(), "{}", path.display());
        assert_eq!(s.params["params"]["scale"].as_f64(), Some(0.25));
    }

    #[test]
    fn lighting_needs_exactly_one_source() {
        let e = parse(&OK.replace("constant = [1, 1, 1]", "")).unwrap_err();
        assert!(e.message.contains("env_map"), "{e}");
    }
}
