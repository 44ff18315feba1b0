//! What each item of `biscale reproduce` runs: the runs (a config of `configs/paper/`, the mesh
//! it is given and the overrides of `--quick`) and the items (a table of the paper) that draw
//! on them. A run several items need (the bunny of Table I is Table II's first column, as in
//! the paper) runs once.

use crate::error::{io_err, PipelineError, Result};
use crate::experiment::config::Experiment;
use std::path::{Path, PathBuf};

/// Where a run's mesh comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshSource {
    /// The config's own `scene.mesh`.
    AsConfigured,
    /// The config's mesh midpoint-subdivided this many times (`biscale generate subdivide`:
    /// about 4x the vertices per level).
    Subdivided(u32),
    /// The generated temple (`biscale generate scene temple`) with the face grid whose vertex
    /// count is nearest to Table I's Temple.
    PaperTemple,
    /// The generated chair (`biscale generate scene chair`) with the face grid whose vertex
    /// count is nearest to Table I's Chair.
    PaperChair,
}

/// The vertex counts the generated scenes are made near: Table I's.
#[derive(Clone, Copy, Debug)]
pub struct PaperSizes {
    pub temple: usize,
    pub chair: usize,
}

/// One run: a config of `configs/paper/`, run into `runs/<name>/`.
#[derive(Clone, Copy, Debug)]
pub struct RunSpec {
    pub name: &'static str,
    /// The file in `configs/paper/`.
    pub config: &'static str,
    /// The experiment name, when not the config's (runs of one config at several meshes).
    pub experiment: Option<&'static str>,
    pub mesh: MeshSource,
    pub quick_mesh: MeshSource,
    /// Overrides of this run in both modes (one config run several ways), before `--quick`'s.
    pub set: &'static [&'static str],
    /// `--quick`'s overrides beside [`QUICK`], for this config's own keys.
    pub quick: &'static [&'static str],
    /// The run whose inset region and error scale this one takes (`report.inset`,
    /// `report.reference_error_scale`), so a figure that sets their images side by side
    /// magnifies the same pixels and shares one colour bar.
    pub inset_from: Option<&'static str>,
}

/// `--quick`'s overrides of every run: coarse transfer (6x8x8 light, 6x16x16 visibility, 4x4
/// local directions), 96x72 images, one timing repeat, no ray-traced reference.
pub const QUICK: &[&str] = &[
    "transfer.cubemap_resolution=8",
    "transfer.visibility_resolution=16",
    "transfer.local_grid=4",
    "runtime.width=96",
    "runtime.height=72",
    "runtime.repeats=1",
    "report.reference=false",
];

const BUNNY_QUICK: &[&str] = &["scene.material.resolution=8", "scene.material.view_grid=4"];

const ARMOR_QUICK: &[&str] = &["scene.material.resolution=8", "scene.material.view_grid=4"];

const CHAIR_QUICK: &[&str] = &[
    "scene.materials.0.resolution=8",
    "scene.materials.0.view_grid=4",
    "scene.materials.1.resolution=8",
    "scene.materials.1.view_grid=4",
    "scene.materials.2.resolution=8",
    "scene.materials.2.view_grid=4",
];

const TEMPLE_QUICK: &[&str] = &[
    "scene.materials.0.resolution=8",
    "scene.materials.1.resolution=8",
    "scene.materials.1.view_grid=4",
    "scene.materials.2.resolution=8",
    "scene.materials.2.view_grid=4",
    "scene.materials.3.view_grid=4",
    "scene.materials.4.resolution=8",
    "scene.materials.4.view_grid=4",
];

/// Shorter sweeps for `--quick` (every kind keeps at least two settings, so each curve of the
/// equal-quality read-off still has a segment).
const EQUAL_QUALITY_QUICK: &[&str] = &[
    "scene.material.view_grid=4",
    "compressors.2.error_budget=[0.01, 0.05, 0.2]",
    "compressors.3.clusters=[4, 8]",
    "compressors.3.components=[2, 4]",
    "compressors.4.clusters=8",
    "compressors.4.components=[8]",
    "compressors.5.terms=[4, 8, 16, 32]",
];

/// Every run, in the order they run.
pub const RUNS: &[RunSpec] = &[
    RunSpec {
        name: "bunny",
        config: "table1_bunny.toml",
        experiment: None,
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: BUNNY_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "bunny-l1",
        config: "table1_bunny.toml",
        experiment: Some("table2_bunny_l1"),
        mesh: MeshSource::Subdivided(1),
        quick_mesh: MeshSource::Subdivided(1),
        set: &[],
        quick: BUNNY_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "bunny-l2",
        config: "table1_bunny.toml",
        experiment: Some("table2_bunny_l2"),
        mesh: MeshSource::Subdivided(2),
        quick_mesh: MeshSource::Subdivided(2),
        set: &[],
        quick: BUNNY_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "armor",
        config: "table1_armor.toml",
        experiment: None,
        mesh: MeshSource::Subdivided(2),
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: ARMOR_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "chair",
        config: "table1_chair.toml",
        experiment: None,
        mesh: MeshSource::PaperChair,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: CHAIR_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "temple",
        config: "table1_temple.toml",
        experiment: None,
        mesh: MeshSource::PaperTemple,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: TEMPLE_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "equal-quality",
        config: "equal_quality.toml",
        experiment: None,
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: EQUAL_QUALITY_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "fig1-bunny",
        config: "fig1_bunny.toml",
        experiment: None,
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: FIG1_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "fig1-bunny-moments",
        config: "fig1_bunny.toml",
        experiment: Some("fig1_bunny_moments"),
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: FIG1_MOMENTS,
        quick: LOW_VS_ALL_QUICK,
        inset_from: Some("fig1-bunny"),
    },
    RunSpec {
        name: "fig5-glossy",
        config: "fig5_glossy.toml",
        experiment: None,
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &[],
        quick: LOW_VS_ALL_QUICK,
        inset_from: None,
    },
    RunSpec {
        name: "fig5-glossy-moments",
        config: "fig5_glossy.toml",
        experiment: Some("fig5_glossy_moments"),
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: MOMENTS,
        quick: LOW_VS_ALL_QUICK,
        inset_from: Some("fig5-glossy"),
    },
    RunSpec {
        name: "fig8-8",
        config: "fig8_bunny.toml",
        experiment: Some("fig8_bunny_8"),
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &["transfer.local_grid=8"],
        quick: &["scene.material.resolution=8", "scene.material.view_grid=4", "transfer.local_grid=2"],
        inset_from: None,
    },
    RunSpec {
        name: "fig8-16",
        config: "fig8_bunny.toml",
        experiment: Some("fig8_bunny_16"),
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &["transfer.local_grid=16"],
        quick: &["scene.material.resolution=8", "scene.material.view_grid=4", "transfer.local_grid=4"],
        inset_from: None,
    },
    RunSpec {
        name: "fig8-32",
        config: "fig8_bunny.toml",
        experiment: Some("fig8_bunny_32"),
        mesh: MeshSource::AsConfigured,
        quick_mesh: MeshSource::AsConfigured,
        set: &["transfer.local_grid=32"],
        quick: &["scene.material.resolution=8", "scene.material.view_grid=4", "transfer.local_grid=8"],
        inset_from: None,
    },
];

/// The light-moments runs of Figs. 1 and 5: the all-frequency gather with each bin's light
/// moments; the SH settings, which moments do not change, are left to the paper-rule run.
const MOMENTS: &[&str] = &["runtime.light_moments=true", "methods=[]"];

/// Fig. 1's moments run: no animation either (its SH setting is the paper-rule run's).
const FIG1_MOMENTS: &[&str] = &[
    "runtime.light_moments=true",
    "methods=[]",
    "runtime.animation.light_frames=0",
    "runtime.animation.camera_frames=0",
];

/// Figs. 1 and 5 at `--quick`: small BTFs and the ground truth traced (the figures are errors
/// against it).
const LOW_VS_ALL_QUICK: &[&str] = &[
    "scene.material.resolution=8",
    "scene.material.view_grid=4",
    "report.reference=true",
    "report.reference_downscale=1",
];

/// Fig. 1 at `--quick`: [`LOW_VS_ALL_QUICK`] and animations of six frames.
const FIG1_QUICK: &[&str] = &[
    "scene.material.resolution=8",
    "scene.material.view_grid=4",
    "report.reference=true",
    "report.reference_downscale=1",
    "runtime.animation.light_frames=6",
    "runtime.animation.camera_frames=6",
];

/// One item: a table of the paper and the runs it is made from.
#[derive(Clone, Copy, Debug)]
pub struct Item {
    /// The name `--only` takes.
    pub name: &'static str,
    pub title: &'static str,
    /// Its file in `tables/` (without `.tex`).
    pub file: &'static str,
    pub runs: &'static [&'static str],
}

pub const ITEMS: &[Item] = &[
    Item { name: "table1", title: "Table I: the scenes", file: "table1", runs: &["bunny", "armor", "chair", "temple"] },
    Item {
        name: "table2",
        title: "Table II: the bunny at three vertex counts",
        file: "table2",
        runs: &["bunny", "bunny-l1", "bunny-l2"],
    },
    Item {
        name: "equal-quality",
        title: "Fig. 6 and the equal-quality comparison",
        file: "equal_quality",
        runs: &["equal-quality"],
    },
    Item {
        name: "low-vs-all",
        title: "Figs. 1 and 5: low- vs all-frequency",
        file: "low_vs_all",
        runs: &["fig1-bunny", "fig1-bunny-moments", "fig5-glossy", "fig5-glossy-moments"],
    },
    Item {
        name: "fig8",
        title: "Fig. 8: local incident-direction resolution",
        file: "fig8",
        runs: &["fig8-8", "fig8-16", "fig8-32"],
    },
    Item { name: "fig3b", title: "Fig. 3(b): the structure of T", file: "fig3b", runs: &["bunny"] },
    Item { name: "fig7", title: "Fig. 7: the temple, five BTFs", file: "fig7", runs: &["temple"] },
    Item {
        name: "animation",
        title: "The light turned and the camera orbited (the paper's video)",
        file: "animation",
        runs: &["fig1-bunny"],
    },
];

/// The items `--only` names (all of them when it names none), in [`ITEMS`] order.
pub fn select(only: &[String]) -> Result<Vec<&'static Item>> {
    let names: Vec<&str> = ITEMS.iter().map(|i| i.name).collect();
    for o in only {
        if !names.contains(&o.as_str()) {
            return Err(PipelineError::Mismatch {
                path: PathBuf::from("--only"),
                what: format!("no item `{o}`; the items are {}", names.join(", ")),
            });
        }
    }
    Ok(ITEMS.iter().filter(|i| only.is_empty() || only.iter().any(|o| o == i.name)).collect())
}

/// The runs `items` need, each once, in [`RUNS`] order.
pub fn runs_of(items: &[&Item]) -> Vec<&'static RunSpec> {
    RUNS.iter().filter(|r| items.iter().any(|i| i.runs.contains(&r.name))).collect()
}

/// The folder of the paper configs: `configs/paper` under the working folder (a checkout),
/// else under the checkout this biscale was built from.
pub fn configs_dir() -> Result<PathBuf> {
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/paper");
    let candidates = [PathBuf::from("configs/paper"), built];
    candidates.iter().find(|d| d.join(RUNS[0].config).is_file()).cloned().ok_or_else(|| PipelineError::Mismatch {
        path: candidates[0].clone(),
        what: "not found here or in the checkout biscale was built from: run `biscale reproduce` in the biscale \
               checkout (it reads configs/paper/ and assets/)"
            .into(),
    })
}

/// A mesh the command made for a run: where it is and how.
#[derive(Clone, Debug)]
pub struct MadeMesh {
    pub path: PathBuf,
    pub how: String,
}

/// The run's experiment: its config with the mesh (made into `meshes` when it is generated),
/// the experiment name, `--quick`'s overrides and the user's `--set` (last, so they win).
pub fn experiment(
    spec: &RunSpec,
    configs: &Path,
    quick: bool,
    user: &[String],
    meshes: &Path,
    sizes: PaperSizes,
) -> Result<(Experiment, Option<MadeMesh>)> {
    let path = configs.join(spec.config);
    let mut overrides: Vec<String> = vec![];
    if let Some(name) = spec.experiment {
        overrides.push(format!("name={}", toml_string(name)));
    }
    overrides.extend(spec.set.iter().map(|s| s.to_string()));
    if quick {
        overrides.extend(QUICK.iter().chain(spec.quick).map(|s| s.to_string()));
    }
    let base = Experiment::load_with(&path, &overrides)?;
    let made = match if quick { spec.quick_mesh } else { spec.mesh } {
        MeshSource::AsConfigured => None,
        MeshSource::Subdivided(levels) => {
            let stem = base.mesh_path.file_stem().map_or("mesh".into(), |s| s.to_string_lossy().into_owned());
            let out = meshes.join(format!("reproduce-{stem}-l{levels}.obj"));
            std::fs::create_dir_all(meshes).map_err(io_err(meshes))?;
            // `force`: the cache's own `meshes/` folder, where a regular file of this name is the
            // cache's (an older biscale's wrote no mark); a link or device there is still refused.
            let mesh = crate::commands::subdivide(&base.mesh_path, levels, false, &out, true)?;
            let how = format!(
                "{} midpoint-subdivided {levels} time{} ({} vertices)",
                base.mesh_path.file_name().map_or(String::new(), |n| n.to_string_lossy().into_owned()),
                if levels == 1 { "" } else { "s" },
                mesh.vertex_count()
            );
            Some(MadeMesh { path: out, how })
        }
        MeshSource::PaperTemple => Some(generated(meshes, "temple", sizes.temple, temple_near(sizes.temple))?),
        MeshSource::PaperChair => Some(generated(meshes, "chair", sizes.chair, chair_near(sizes.chair))?),
    };
    let Some(m) = made else { return Ok((load(&path, overrides, user)?, None)) };
    let abs = std::path::absolute(&m.path).map_err(io_err(&m.path))?;
    overrides.push(format!("scene.mesh={}", toml_string(&abs.to_string_lossy())));
    Ok((load(&path, overrides, user)?, Some(m)))
}

/// A generated scene made near `target` vertices, written into `meshes`.
fn generated(
    meshes: &Path,
    what: &str,
    target: usize,
    (cell, mesh): (f32, biscale_core::geometry::Mesh),
) -> Result<MadeMesh> {
    let out = meshes.join(format!("reproduce-{what}-{target}.obj"));
    std::fs::create_dir_all(meshes).map_err(io_err(meshes))?;
    biscale_core::io::write_atomic_bytes(&out, mesh.to_obj().as_bytes())?;
    let how = format!(
        "the generated {what} with {cell:.4}-unit face cells ({} vertices; the nearest to {target})",
        mesh.vertex_count()
    );
    Ok(MadeMesh { path: out, how })
}

fn load(path: &Path, mut overrides: Vec<String>, user: &[String]) -> Result<Experiment> {
    overrides.extend(user.iter().cloned());
    Ok(Experiment::load_with(path, &overrides)?)
}

/// A TOML string literal of `s`.
fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// The generated temple whose vertex count is nearest to `target`, and its face cell: the
/// cell is bisected on a log scale between 0.02 and 4 units (the count falls as the cell
/// grows, in steps, so the nearest of every size tried is kept).
pub fn temple_near(target: usize) -> (f32, biscale_core::geometry::Mesh) {
    use crate::temple::{build, TempleOptions};
    near(target, (0.02, 4.0), |cell| build(&TempleOptions { cell, ..TempleOptions::default() }))
}

/// The generated chair with the face cell (between 0.005 and 0.5 units) whose vertex count is
/// nearest to `target`, and that cell.
pub fn chair_near(target: usize) -> (f32, biscale_core::geometry::Mesh) {
    use crate::chair::{build, ChairOptions};
    near(target, (0.005, 0.5), |cell| build(&ChairOptions { cell }))
}

/// Bisection on the log of a scene's face cell in `(lo, hi)` for the mesh nearest `target`
/// vertices (finer cells, more vertices).
fn near(
    target: usize,
    (lo, hi): (f32, f32),
    make: impl Fn(f32) -> biscale_core::geometry::Mesh,
) -> (f32, biscale_core::geometry::Mesh) {
    let (mut lo, mut hi) = (lo.ln(), hi.ln());
    let mut best: Option<(usize, f32, biscale_core::geometry::Mesh)> = None;
    for _ in 0..24 {
        let mid = 0.5 * (lo + hi);
        let cell = mid.exp();
        let mesh = make(cell);
        let n = mesh.vertex_count();
        let off = n.abs_diff(target);
        if best.as_ref().is_none_or(|(b, _, _)| off < *b) {
            best = Some((off, cell, mesh));
        }
        match n.cmp(&target) {
            std::cmp::Ordering::Greater => lo = mid,
            std::cmp::Ordering::Less => hi = mid,
            std::cmp::Ordering::Equal => break,
        }
    }
    let (_, cell, mesh) = best.expect("at least one size is tried");
    (cell, mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_item_names_runs_that_exist_and_only_selects_known_items() {
        for item in ITEMS {
            for r in item.runs {
                assert!(RUNS.iter().any(|s| s.name == *r), "{}: {r}", item.name);
            }
        }
        assert_eq!(select(&[]).unwrap().len(), ITEMS.len());
        let two = select(&["table2".into()]).unwrap();
        let runs: Vec<&str> = runs_of(&two).iter().map(|r| r.name).collect();
        assert_eq!(runs, ["bunny", "bunny-l1", "bunny-l2"]);
        let e = select(&["table3".into()]).unwrap_err().to_string();
        assert!(e.contains("--only") && e.contains("table3") && e.contains("equal-quality"), "{e}");
    }

    #[test]
    fn the_generated_scenes_are_made_near_the_papers_vertex_counts() {
        let target = super::super::published::Published::get().scene("Temple").unwrap().figures.vertices as usize;
        let (cell, mesh) = temple_near(target);
        let n = mesh.vertex_count();
        assert!(n.abs_diff(target) * 20 < target, "{n} vertices at cell {cell} for {target}");
        // The default cell is the bundled temple.
        assert_eq!(temple_near(5336).1.vertex_count(), 5336);
        // The chair likewise, and the bundled one is its default.
        let target = super::super::published::Published::get().scene("Chair").unwrap().figures.vertices as usize;
        let (cell, mesh) = chair_near(target);
        let n = mesh.vertex_count();
        assert!(n.abs_diff(target) * 20 < target, "{n} vertices at cell {cell} for {target}");
        let bundled = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/chair.obj");
        let v = std::fs::read_to_string(bundled).unwrap().lines().filter(|l| l.starts_with("v ")).count();
        assert_eq!(
            v,
            crate::chair::build(&Default::default()).vertex_count(),
            "assets/meshes/chair.obj is the default"
        );
    }

    #[test]
    fn every_config_loads_in_both_modes() {
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/paper");
        for spec in RUNS {
            for quick in [false, true] {
                let path = configs.join(spec.config);
                let mut o: Vec<String> = spec.set.iter().map(|s| s.to_string()).collect();
                if quick {
                    o.extend(QUICK.iter().chain(spec.quick).map(|s| s.to_string()));
                }
                Experiment::load_with(&path, &o).unwrap_or_else(|e| panic!("{} quick={quick}: {e}", spec.name));
            }
        }
    }
}
