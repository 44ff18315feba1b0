//! Local-PCA compressed BTFs (Müller, Meseth, Klein 2004, "Compression and real-time rendering
//! of measured BTFs using local PCA"): the texels' apparent BRDFs clustered, each cluster kept
//! as a mean and a few principal components ("eigen-BRDFs"), each texel as its cluster and its
//! weights.
//!
//! The vector compressed per texel is the texel's whole table `b(u, e_v, d_j)` over views `v`
//! and light bins `j`, RGB interleaved: `D = 3 V M` values, exactly the dense layout
//! (`data[(texel V + v) M + j]`), so the clustering reads the dense table in place. The build is
//! the shared clustered PCA ([`crate::linalg::cpca`]), the one the CPCA transfer compressor
//! uses; it minimises the squared error of the table, so the reported error is the relative
//! RMS of the table, `||B - B~||_F / ||B||_F`.
//!
//! Evaluation ([`LpcaBtf::eval_into`]) uses the dense path's texel lookup and view weights
//! ([`super::btf::texel_of`], [`super::btf::view_weights`]), so a setting that keeps every component
//! reproduces the dense values to rounding.
//!
//! | array | type | length | meaning |
//! |---|---|---|---|
//! | `basis` | f32 | `K (C + 1) D` | cluster k's mean at `[(k (C+1)) D..][..D]`, component c at `[(k (C+1) + c) D..][..D]` |
//! | `cluster` | u16 | units | a unit's cluster; `K` marks an all-zero unit (evaluates to 0) |
//! | `weights` | f32 | units `C` | a unit's weight of component c at `[u C + c - 1]` |
//!
//! The unit ([`LpcaUnit`]) is a texel (`D = 3 V M`, Müller et al.), or a (texel, view) pair
//! (`D = 3 M`, unit `t V + v`): a per-view decomposition with more, shorter vectors. Either is
//! a contiguous run of the dense table.

use super::btf::{texel_of, view_weights};
use super::Btf;
use crate::artifact::{Artifact, ArtifactError, Field};
use crate::basis::LocalBasis;
use crate::compress::ArrayData;
use crate::error::{CoreError, Result};
use crate::linalg::{clustered_pca, CpcaSettings, DenseRows};
use crate::sampling::HemisphereGrid;
use crate::Rgb;
use glam::{Vec2, Vec3};

/// The artifact kind of a stored LPCA BTF.
pub const LPCA_ARTIFACT: &str = "lpca-btf";

/// Largest build model (2 GiB, the shared clustered PCA's limit); beyond, a request is refused
/// with its estimate.
pub const MAX_LPCA_BYTES: u64 = crate::linalg::cpca::MAX_BUILD_BYTES;

/// Default rounds of the LPCA build. On the bunny's 64x64 patch (16 clusters x 4 components)
/// 6 rounds take 12.7 s at 18.82% table error, 12 rounds 26.2 s at 18.65% (BENCHMARKS.md): the
/// last rounds move few texels.
pub const DEFAULT_LPCA_ITERATIONS: usize = 6;

/// What one clustered vector is (`unit = "texel"` or `"view"` in a config).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LpcaUnit {
    /// A texel's whole apparent BRDF over views and lights, `3 V M` values (Müller et al.).
    #[default]
    Texel,
    /// One (texel, view) pair's values over the lights, `3 M` values: a per-view
    /// decomposition, more rows of fewer values.
    View,
}

/// How the eigen-BRDFs and weights are stored (`quantize = "f32"`, `"f16"` or `"u8"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LpcaQuantize {
    #[default]
    F32,
    /// IEEE half floats (11-bit significand).
    F16,
    /// 8-bit codes with one scale per category (four: cluster means, eigen-BRDFs, the first
    /// component's weights, the other weights; Müller et al. also scale per category). Means
    /// are non-negative and coded `0..=255` with `s = max / 255`; the others are signed,
    /// `-127..=127` with `s = max |x| / 127`. Each value is off by at most `s / 2`.
    U8,
}

impl LpcaQuantize {
    pub fn name(&self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::U8 => "u8",
        }
    }

    fn bytes_per_value(&self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F16 => 2,
            Self::U8 => 1,
        }
    }
}

/// The settings of a local-PCA BTF; a config's `representation = { kind = "lpca", ... }`
/// table deserializes into it, every key optional ([`LpcaSettings::default`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct LpcaSettings {
    /// Clusters `k_B` of texels (1..=texels, at most 65534); 16 by default.
    pub clusters: usize,
    /// Principal components `c_B` per cluster besides the mean (1..=D); 4 by default.
    pub components: usize,
    /// Assignment/refit rounds of the clustered PCA (at most; it stops when no unit changes
    /// cluster). [`DEFAULT_LPCA_ITERATIONS`] by default.
    pub iterations: usize,
    /// `texel` (default: a texel's table over views and lights is one vector) or `view`
    /// (each texel's view is one vector over the lights).
    pub unit: LpcaUnit,
    /// Storage of the eigen-BRDFs and weights: `f32` (default), `f16` or `u8`.
    pub quantize: LpcaQuantize,
}

impl Default for LpcaSettings {
    /// 16 clusters of 4 components, texel units, f32, [`DEFAULT_LPCA_ITERATIONS`] rounds.
    fn default() -> Self {
        Self::new(16, 4)
    }
}

impl LpcaSettings {
    pub fn new(clusters: usize, components: usize) -> Self {
        Self {
            clusters,
            components,
            iterations: DEFAULT_LPCA_ITERATIONS,
            unit: LpcaUnit::Texel,
            quantize: LpcaQuantize::F32,
        }
    }

    pub fn quantized(self, quantize: LpcaQuantize) -> Self {
        Self { quantize, ..self }
    }

    pub fn per_view(self) -> Self {
        Self { unit: LpcaUnit::View, ..self }
    }
}

/// A BTF compressed by local PCA (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct LpcaBtf {
    spatial: [u32; 2],
    local_basis: LocalBasis,
    view_grid: Option<HemisphereGrid>,
    name: String,
    unit: LpcaUnit,
    clusters: usize,
    components: usize,
    /// The stored values, dequantized (what an evaluation computes with).
    basis: Vec<f32>,
    cluster: Vec<u16>,
    weights: Vec<f32>,
    quantize: LpcaQuantize,
    /// The four category scales of [`LpcaQuantize::U8`] (zeros otherwise).
    scales: [f32; 4],
}

/// What a compression achieved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LpcaReport {
    /// Relative RMS error of the table, `||B - B~||_F / ||B||_F` (0 for an all-zero table).
    pub relative_rms_error: f64,
    /// Largest absolute error of one value.
    pub max_abs_error: f64,
    /// Clusters kept (empty ones are dropped).
    pub clusters: usize,
    pub seconds: f64,
}

impl LpcaBtf {
    /// Compress `btf` (module docs). Errors name the BTF and the setting that does not fit.
    pub fn compress(btf: &Btf, settings: &LpcaSettings, seed: u64) -> Result<(Self, LpcaReport)> {
        let start = std::time::Instant::now();
        let texels = btf.texel_count();
        let (units, d) = match settings.unit {
            LpcaUnit::Texel => (texels, 3 * btf.view_count() * btf.light_count()),
            LpcaUnit::View => (texels * btf.view_count(), 3 * btf.light_count()),
        };
        let bad = |m: String| Err(CoreError::Invalid(format!("BTF '{}': lpca {m}", btf.name())));
        let what = match settings.unit {
            LpcaUnit::Texel => format!("the patch has {texels} texels"),
            LpcaUnit::View => format!("the patch has {texels} texels x {} views", btf.view_count()),
        };
        if settings.clusters == 0 || settings.clusters > units.min(u16::MAX as usize - 1) {
            return bad(format!(
                "clusters = {} must be in 1..={} ({what})",
                settings.clusters,
                units.min(u16::MAX as usize - 1)
            ));
        }
        if settings.components == 0 || settings.components > d {
            let per = match settings.unit {
                LpcaUnit::Texel => {
                    format!("a texel's table has {} views x {} lights x RGB", btf.view_count(), btf.light_count())
                }
                LpcaUnit::View => format!("a view's table has {} lights x RGB", btf.light_count()),
            };
            return bad(format!("components = {} must be in 1..={d} ({per} = {d} values)", settings.components));
        }
        if settings.iterations == 0 {
            return bad("iterations must be at least 1".into());
        }
        let need = crate::linalg::cpca::build_bytes(settings.clusters, settings.components, d);
        if need > MAX_LPCA_BYTES {
            return bad(format!(
                "{} clusters x {} vectors of {d} values need about {:.1} GiB to build, over the {} GiB limit",
                settings.clusters,
                settings.components + 1,
                need as f64 / (1u64 << 30) as f64,
                MAX_LPCA_BYTES >> 30
            ));
        }
        let values: &[f32] = bytemuck::cast_slice(btf.data());
        let rows = DenseRows { dim: d, data: values };
        let cpca = CpcaSettings {
            clusters: settings.clusters,
            components: settings.components,
            iterations: settings.iterations,
            // Each round warm-starts from the previous components, so one power iteration and
            // 4 extra columns keep the error of 2 and 8 (within 0.02% of the table on the
            // bunny's 64x64 patch) at half the cost.
            power_iterations: 1,
            oversampling: 4,
        };
        let fit = clustered_pca(&rows, &cpca, seed, &|_| {});
        let mut out = Self {
            spatial: btf.spatial(),
            local_basis: btf.local_basis(),
            view_grid: btf.view_grid(),
            name: btf.name().to_string(),
            unit: settings.unit,
            clusters: fit.clusters,
            components: fit.components,
            basis: fit.basis,
            cluster: fit.cluster.iter().map(|&k| k as u16).collect(),
            weights: fit.coeffs,
            quantize: LpcaQuantize::F32,
            scales: [0.0; 4],
        };
        out.quantize(settings.quantize, d);
        let (relative_rms_error, max) = out.table_error(btf);
        let report = LpcaReport {
            relative_rms_error,
            max_abs_error: max,
            clusters: out.clusters,
            seconds: start.elapsed().as_secs_f64(),
        };
        Ok((out, report))
    }

    /// Round the basis and weights to `q` (module docs of [`LpcaQuantize`]); `d` values per
    /// vector.
    fn quantize(&mut self, q: LpcaQuantize, d: usize) {
        self.quantize = q;
        match q {
            LpcaQuantize::F32 => {}
            LpcaQuantize::F16 => {
                for x in self.basis.iter_mut().chain(self.weights.iter_mut()) {
                    *x = half::f16::from_f32(*x).to_f32();
                }
            }
            LpcaQuantize::U8 => {
                let c = self.components;
                let is_mean = |i: usize| (i / d.max(1)).is_multiple_of(c + 1);
                let max_abs = |it: &mut dyn Iterator<Item = f32>| it.fold(0.0f32, |m, x| m.max(x.abs()));
                let means = max_abs(&mut self.basis.iter().enumerate().filter(|(i, _)| is_mean(*i)).map(|(_, &x)| x));
                let comps = max_abs(&mut self.basis.iter().enumerate().filter(|(i, _)| !is_mean(*i)).map(|(_, &x)| x));
                let first = max_abs(
                    &mut self.weights.iter().enumerate().filter(|(i, _)| i.is_multiple_of(c.max(1))).map(|(_, &x)| x),
                );
                let rest = max_abs(
                    &mut self.weights.iter().enumerate().filter(|(i, _)| !i.is_multiple_of(c.max(1))).map(|(_, &x)| x),
                );
                self.scales = [means / 255.0, comps / 127.0, first / 127.0, rest / 127.0];
                let code =
                    |x: f32, s: f32, lo: f32, hi: f32| if s > 0.0 { (x / s).round().clamp(lo, hi) * s } else { 0.0 };
                let [sm, sc, sf, sr] = self.scales;
                for (i, x) in self.basis.iter_mut().enumerate() {
                    *x = if is_mean(i) { code(*x, sm, 0.0, 255.0) } else { code(*x, sc, -127.0, 127.0) };
                }
                for (i, x) in self.weights.iter_mut().enumerate() {
                    *x = if i.is_multiple_of(c.max(1)) {
                        code(*x, sf, -127.0, 127.0)
                    } else {
                        code(*x, sr, -127.0, 127.0)
                    };
                }
            }
        }
    }

    /// This f32 BTF with its basis and weights stored as `q` (the same rounding as
    /// [`Self::compress`] with that quantization: one fit serves every storage width). Errors
    /// when it is already quantized (rounding twice would compound).
    pub fn quantized(&self, q: LpcaQuantize) -> Result<Self> {
        if self.quantize != LpcaQuantize::F32 {
            return Err(CoreError::Invalid(format!(
                "BTF '{}' is stored as {}; quantize its f32 form",
                self.name,
                self.quantize.name()
            )));
        }
        let mut out = self.clone();
        out.quantize(q, self.unit_values());
        Ok(out)
    }

    /// Whether `btf` has this BTF's patch size, light basis and view grid.
    pub fn fits(&self, btf: &Btf) -> bool {
        self.spatial == btf.spatial() && self.local_basis == btf.local_basis() && self.view_grid == btf.view_grid()
    }

    /// How far this is from `btf` (the dense table it was built from): the relative RMS error
    /// of the table, `||B - B~||_F / ||B||_F`, and the largest absolute error of one value.
    ///
    /// # Panics
    /// If `btf` does not [`Self::fits`] (a caller bug).
    pub fn table_error(&self, btf: &Btf) -> (f64, f64) {
        let values: &[f32] = bytemuck::cast_slice(btf.data());
        let d = self.unit_values();
        assert!(self.fits(btf), "table_error: the BTF has another shape");
        let (mut num, mut den, mut max) = (0.0f64, 0.0f64, 0.0f64);
        let mut row = vec![0.0f32; d];
        for (t, x) in values.chunks_exact(d.max(1)).enumerate() {
            self.decode_row(t, &mut row);
            for (&a, &b) in x.iter().zip(&row) {
                let e = a as f64 - b as f64;
                num += e * e;
                den += a as f64 * a as f64;
                max = max.max(e.abs());
            }
        }
        (crate::stats::relative_l2(num, den), max)
    }

    /// The values of one unit (a texel's table, or a texel's view), RGB interleaved,
    /// reconstructed in f64 and rounded once.
    fn decode_row(&self, t: usize, out: &mut [f32]) {
        let (d, c) = (out.len(), self.components);
        let k = self.cluster[t] as usize;
        if k >= self.clusters {
            out.fill(0.0);
            return;
        }
        let vector = |j: usize| &self.basis[(k * (c + 1) + j) * d..(k * (c + 1) + j + 1) * d];
        let w = &self.weights[t * c..(t + 1) * c];
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = vector(0)[i] as f64;
            for (j, &wj) in w.iter().enumerate() {
                acc += wj as f64 * vector(j + 1)[i] as f64;
            }
            *o = acc as f32;
        }
    }

    /// The dense table this represents (for the shaders that take dense BTFs).
    pub fn decode(&self) -> Result<Btf> {
        let d = self.unit_values();
        let units = self.cluster.len();
        let mut values = vec![0.0f32; units * d];
        for (t, row) in values.chunks_mut(d.max(1)).enumerate().take(units) {
            self.decode_row(t, row);
        }
        let data: Vec<Rgb> = values.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        Btf::new(self.spatial, self.local_basis, self.view_grid, data, format!("{} (lpca)", self.name))
    }

    /// Values per clustered unit.
    fn unit_values(&self) -> usize {
        match self.unit {
            LpcaUnit::Texel => 3 * self.view_count() * self.light_count(),
            LpcaUnit::View => 3 * self.light_count(),
        }
    }

    fn view_count(&self) -> usize {
        self.view_grid.map_or(1, |g| g.len())
    }

    fn light_count(&self) -> usize {
        self.local_basis.len()
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Patch size in texels.
    pub fn spatial(&self) -> [u32; 2] {
        self.spatial
    }

    /// The light directions of every segment (the basis of the `L*` it is dotted with).
    pub fn local_basis(&self) -> LocalBasis {
        self.local_basis
    }

    /// View samples (`None`: view-independent).
    pub fn view_grid(&self) -> Option<HemisphereGrid> {
        self.view_grid
    }

    pub fn unit(&self) -> LpcaUnit {
        self.unit
    }

    /// Light segments (`3 M` values each, one per view sample) in one clustered vector:
    /// `V` per texel, 1 per view.
    pub fn segments_per_unit(&self) -> usize {
        match self.unit {
            LpcaUnit::Texel => self.view_count(),
            LpcaUnit::View => 1,
        }
    }

    /// The unit holding view sample `view` of `texel`, and the segment of its vector that
    /// holds that view.
    pub fn unit_of(&self, texel: usize, view: usize) -> (usize, usize) {
        match self.unit {
            LpcaUnit::Texel => (texel, view),
            LpcaUnit::View => (texel * self.view_count() + view, 0),
        }
    }

    /// The cluster of `unit`; `None` for an all-zero unit.
    pub fn cluster_of(&self, unit: usize) -> Option<usize> {
        let k = self.cluster[unit] as usize;
        (k < self.clusters).then_some(k)
    }

    /// The weights of `unit` (`components` values; component 0, the mean, has weight 1).
    pub fn unit_weights(&self, unit: usize) -> &[f32] {
        &self.weights[unit * self.components..(unit + 1) * self.components]
    }

    /// Segment `segment` (`3 M` values, RGB interleaved) of cluster `k`'s vector `c`: its mean
    /// for `c = 0`, eigen-BRDF `c` otherwise.
    pub fn segment(&self, k: usize, c: usize, segment: usize) -> &[f32] {
        let (d, m3) = (self.unit_values(), 3 * self.light_count());
        &self.basis[(k * (self.components + 1) + c) * d + segment * m3..][..m3]
    }

    /// This BTF with every light segment of every mean and eigen-BRDF mapped by `f` (from
    /// `3 M` values to `3 M'` values of `local_basis`, RGB interleaved). The weights and
    /// clusters are kept, so for a linear `f` the result is exactly the LPCA of the mapped
    /// table: the radiance transfer texture of an LPCA BTF is an LPCA BTF whose eigen-BRDFs
    /// are projected (Müller et al. project theirs into SH the same way). The mapped values
    /// are stored as f32.
    pub fn map_lights(
        &self,
        local_basis: LocalBasis,
        name: impl Into<String>,
        f: impl Fn(&[f32], &mut [f32]) + Sync,
    ) -> Self {
        use rayon::prelude::*;
        let (m3, n3) = (3 * self.light_count(), 3 * local_basis.len());
        let basis: Vec<f32> = self
            .basis
            .par_chunks(m3.max(1))
            .flat_map_iter(|seg| {
                let mut out = vec![0.0f32; n3];
                f(seg, &mut out);
                out
            })
            .collect();
        Self {
            spatial: self.spatial,
            local_basis,
            view_grid: self.view_grid,
            name: name.into(),
            unit: self.unit,
            clusters: self.clusters,
            components: self.components,
            basis,
            cluster: self.cluster.clone(),
            weights: self.weights.clone(),
            quantize: LpcaQuantize::F32,
            scales: [0.0; 4],
        }
    }

    /// This BTF with only its first `components` eigen-BRDFs per cluster (the largest: each
    /// cluster's components are in decreasing order of variance), the cheaper evaluation the
    /// runtime can switch to while the light moves (Müller et al. 2004 drop components during
    /// rotation). Errors unless `1 <= components <= self.components()`.
    pub fn truncated(&self, components: usize) -> Result<Self> {
        let c = self.components;
        if components == 0 || components > c {
            return Err(CoreError::Invalid(format!(
                "BTF '{}': keep 1..={c} of its lpca components, not {components}",
                self.name
            )));
        }
        let d = self.unit_values();
        let mut basis = Vec::with_capacity(self.clusters * (components + 1) * d);
        for k in 0..self.clusters {
            basis.extend_from_slice(&self.basis[k * (c + 1) * d..(k * (c + 1) + components + 1) * d]);
        }
        let weights = self.weights.chunks_exact(c.max(1)).flat_map(|w| w[..components].iter().copied()).collect();
        Ok(Self {
            spatial: self.spatial,
            local_basis: self.local_basis,
            view_grid: self.view_grid,
            name: format!("{} (first {components} of {c} components)", self.name),
            unit: self.unit,
            clusters: self.clusters,
            components,
            basis,
            cluster: self.cluster.clone(),
            weights,
            quantize: self.quantize,
            scales: self.scales,
        })
    }

    /// The values of `unit` (a texel's table or a texel's view, RGB interleaved), reconstructed
    /// in f64 and rounded once.
    ///
    /// # Panics
    /// If `out` does not hold one unit (a caller bug).
    pub fn decode_unit(&self, unit: usize, out: &mut [f32]) {
        assert_eq!(out.len(), self.unit_values(), "decode_unit: one unit's values");
        self.decode_row(unit, out);
    }

    /// The stored means and eigen-BRDFs, dequantized: cluster `k`'s vector `c` (0 = mean) is
    /// `[(k (C + 1) + c) D..][..D]`, `D` values per unit.
    pub fn basis_values(&self) -> &[f32] {
        &self.basis
    }

    /// Every unit's weights, `C` per unit, dequantized.
    pub fn weight_values(&self) -> &[f32] {
        &self.weights
    }

    /// Every unit's cluster id (`clusters()` marks an all-zero unit).
    pub fn cluster_ids(&self) -> &[u16] {
        &self.cluster
    }

    /// Number of units (texels, or texel-views).
    pub fn units(&self) -> usize {
        self.cluster.len()
    }

    pub fn clusters(&self) -> usize {
        self.clusters
    }

    pub fn components(&self) -> usize {
        self.components
    }

    /// The compressed BTF as a biscale artifact (kind [`LPCA_ARTIFACT`]).
    pub fn to_artifact(&self) -> Artifact {
        Artifact::new(LPCA_ARTIFACT)
            .with("name", Field::Str(self.name.clone()))
            .with("width", Field::U64(self.spatial[0] as u64))
            .with("height", Field::U64(self.spatial[1] as u64))
            .with("local_basis", Field::Str(self.local_basis.tag()))
            .with("view_grid", Field::U64(self.view_grid.map_or(0, |g| g.m as u64)))
            .with("unit", Field::Str(self.unit_name().into()))
            .with("clusters", Field::U64(self.clusters as u64))
            .with("components", Field::U64(self.components as u64))
            .with("quantize", Field::Str(self.quantize.name().into()))
            .with("scales", Field::Str(self.scales.map(|x| x.to_bits().to_string()).join(",")))
            .with_array("basis", ArrayData::F32(self.basis.clone()))
            .with_array("cluster", ArrayData::U16(self.cluster.clone()))
            .with_array("weights", ArrayData::F32(self.weights.clone()))
    }

    fn unit_name(&self) -> &'static str {
        match self.unit {
            LpcaUnit::Texel => "texel",
            LpcaUnit::View => "view",
        }
    }

    /// Read an artifact written by [`Self::to_artifact`]; every size, id and value is checked
    /// before it is used, so a corrupt file is an error that names it.
    pub fn from_artifact(mut a: Artifact) -> std::result::Result<Self, ArtifactError> {
        a.expect_kind(LPCA_ARTIFACT)?;
        let name = a.str("name")?.to_string();
        let (w, h, view_m) = (a.u64("width")?, a.u64("height")?, a.u64("view_grid")?);
        if !(1..=4096).contains(&w) || !(1..=4096).contains(&h) || view_m > 64 {
            return Err(a.corrupt(format!("size {w}x{h} texels, view grid {view_m}")));
        }
        let local_basis = LocalBasis::parse(a.str("local_basis")?).map_err(|e| a.corrupt(e.to_string()))?;
        let view_grid = (view_m > 0).then(|| HemisphereGrid::new(view_m as u32));
        let unit = match a.str("unit")? {
            "texel" => LpcaUnit::Texel,
            "view" => LpcaUnit::View,
            other => return Err(a.corrupt(format!("unit '{other}'"))),
        };
        let (clusters, components) = (a.usize("clusters")?, a.usize("components")?);
        let quantize = match a.str("quantize")? {
            "f32" => LpcaQuantize::F32,
            "f16" => LpcaQuantize::F16,
            "u8" => LpcaQuantize::U8,
            other => return Err(a.corrupt(format!("quantize '{other}'"))),
        };
        let scales: Vec<f32> =
            a.str("scales")?.split(',').filter_map(|x| x.parse::<u32>().ok()).map(f32::from_bits).collect();
        let Ok(scales) = <[f32; 4]>::try_from(scales) else { return Err(a.corrupt("scales")) };
        let views = view_grid.map_or(1, |g| g.len());
        let texels = (w * h) as usize;
        let (units, d) = match unit {
            LpcaUnit::Texel => (texels, 3 * views * local_basis.len()),
            LpcaUnit::View => (texels * views, 3 * local_basis.len()),
        };
        if clusters > units || components > d {
            return Err(a.corrupt(format!("{clusters} clusters x {components} components for {units} units of {d}")));
        }
        let want = [("basis", clusters * (components + 1) * d), ("cluster", units), ("weights", units * components)];
        let mut arrays = vec![];
        for (n, len) in want {
            let data = a.take_array(n)?;
            if data.len() != len {
                return Err(a.corrupt(format!("array '{n}' has {} elements, expected {len}", data.len())));
            }
            arrays.push(data);
        }
        let (ArrayData::F32(basis), ArrayData::U16(cluster), ArrayData::F32(weights)) =
            (arrays.remove(0), arrays.remove(0), arrays.remove(0))
        else {
            return Err(a.corrupt("array types (basis f32, cluster u16, weights f32)"));
        };
        if cluster.iter().any(|&k| k as usize > clusters) {
            return Err(a.corrupt(format!("a cluster id above {clusters}")));
        }
        if !basis.iter().chain(&weights).all(|x| x.is_finite()) {
            return Err(a.corrupt("non-finite basis or weight"));
        }
        Ok(Self {
            spatial: [w as u32, h as u32],
            local_basis,
            view_grid,
            name,
            unit,
            clusters,
            components,
            basis,
            cluster,
            weights,
            quantize,
            scales,
        })
    }

    /// Stored bytes: the basis and weights at the quantization's width (plus the four scales
    /// of u8) and the u16 cluster ids.
    pub fn bytes(&self) -> u64 {
        let scales = if self.quantize == LpcaQuantize::U8 { 16 } else { 0 };
        ((self.basis.len() + self.weights.len()) * self.quantize.bytes_per_value() + self.cluster.len() * 2 + scales)
            as u64
    }

    pub fn quantization(&self) -> LpcaQuantize {
        self.quantize
    }

    /// `b(u, e, d_j)` for every light bin `j` at patch coordinates `texel_uv` and local view
    /// `view_local`: the dense path's nearest texel and bilinear view weights, each view sample
    /// reconstructed from the texel's cluster (`sum_c a_c E_kc(e_v)`, `a = (1, weights)`), in
    /// f32.
    ///
    /// # Panics
    /// If `out.len()` is not the light count (a caller bug).
    pub fn eval_into(&self, texel_uv: Vec2, view_local: Vec3, out: &mut [Rgb]) {
        let m = self.light_count();
        assert_eq!(out.len(), m, "eval_into: output must hold one value per light bin");
        out.fill([0.0; 3]);
        let t = texel_of(self.spatial, texel_uv);
        let (c, d) = (self.components, self.unit_values());
        for (v, wv) in view_weights(self.view_grid, view_local) {
            if wv == 0.0 {
                continue;
            }
            // The unit holding (t, v) and where view v starts in its vector.
            let (u, offset) = match self.unit {
                LpcaUnit::Texel => (t, v * 3 * m),
                LpcaUnit::View => (t * self.view_count() + v, 0),
            };
            let k = self.cluster[u] as usize;
            if k >= self.clusters {
                continue;
            }
            let w = &self.weights[u * c..(u + 1) * c];
            // Flat f32 runs (RGB interleaved on both sides), so the loop vectorizes.
            let flat: &mut [f32] = bytemuck::cast_slice_mut(out);
            for j in 0..=c {
                let a = wv * if j == 0 { 1.0 } else { w[j - 1] };
                let seg = &self.basis[(k * (c + 1) + j) * d + offset..][..3 * m];
                for (o, e) in flat.iter_mut().zip(seg) {
                    *o += a * e;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
