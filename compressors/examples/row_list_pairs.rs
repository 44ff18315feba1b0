//! What sharing the row lists' pairs would buy a saved bicluster form's gather: a measurement,
//! not a form.
//!
//! Pass 2 of the bicluster gather (each row sums its biclusters' scalars) is most of the
//! gather's time, and it is bound by the row lists' entries (BENCHMARKS, "The bicluster gather:
//! what its time is not"). Two biclusters that appear together in many rows could be summed
//! once into a pair scalar, and each of those rows would list the pair instead of both. This
//! example builds such pairs by rounds, in the manner of Re-Pair: each round counts every
//! pair of ids within a row (per block), takes the pairs seen in at least `--min-rows` rows
//! in decreasing count, and replaces them greedily row by row; a pair may name an earlier
//! round's pair. Then it times the plain gather (the library's, one thread) against a
//! prototype gather of the paired lists (pass 1 as the library's, the pairs in order, the
//! shorter row lists), after checking the two agree to f32 rounding.
//!
//! ```text
//! cargo run --release -p biscale-compressors --example bicluster_bench -- --blocks 1024 --runs 1 --save /tmp/bunny.bsf
//! cargo run --release -p biscale-compressors --example row_list_pairs -- /tmp/bunny.b1024.bsf [--rounds 8] [--min-rows 3]
//! ```

use biscale_compressors::bicluster::BiclusterView;
use biscale_compressors::registry;
use biscale_compressors::testing::random_light;
use biscale_core::compress::CompressedForm;
use biscale_core::gather::relative_l2_error;
use biscale_core::stats::median;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

/// Measure what pair sums would save on saved bicluster forms.
#[derive(clap::Parser)]
struct Args {
    /// Saved bicluster forms (`.bsf`).
    forms: Vec<PathBuf>,
    /// Pairing rounds at most (a round's pairs may name the earlier rounds').
    #[arg(long, default_value_t = 8)]
    rounds: usize,
    /// A pair is made only when it replaces two entries in at least this many rows.
    #[arg(long, default_value_t = 3)]
    min_rows: u32,
    /// Interleaved timing rounds (medians).
    #[arg(long, default_value_t = 21)]
    timing_rounds: usize,
}

/// One block's paired row lists: `pairs[p] = (x, y)` defines id `nb + p` as `x + y` (ids
/// block-local, `x, y < nb + p`, `nb` the block's biclusters), and row `i` lists the ids
/// `ids[ptr[i]..ptr[i + 1]]` (flat, as the form stores row lists).
struct Paired {
    pairs: Vec<(u32, u32)>,
    ptr: Vec<u32>,
    ids: Vec<u32>,
}

fn pair_block(mut lists: Vec<Vec<u32>>, nb: usize, rounds: usize, min_rows: u32) -> Paired {
    let mut pairs: Vec<(u32, u32)> = vec![];
    for _ in 0..rounds {
        let mut counts: HashMap<(u32, u32), u32> = HashMap::new();
        for l in &lists {
            for a in 0..l.len() {
                for b in a + 1..l.len() {
                    *counts.entry((l[a], l[b])).or_default() += 1;
                }
            }
        }
        let mut ranked: Vec<((u32, u32), u32)> = counts.into_iter().filter(|&(_, c)| c >= min_rows).collect();
        ranked.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let rank: HashMap<(u32, u32), usize> = ranked.iter().enumerate().map(|(i, p)| (p.0, i)).collect();
        // Each row takes its pairs best-ranked first, each id at most once.
        let mut chosen: Vec<Vec<(usize, usize, usize)>> = Vec::with_capacity(lists.len());
        let mut used = vec![0u32; ranked.len()];
        for l in &lists {
            let mut cand = vec![];
            for a in 0..l.len() {
                for b in a + 1..l.len() {
                    if let Some(&r) = rank.get(&(l[a], l[b])) {
                        cand.push((r, a, b));
                    }
                }
            }
            cand.sort_unstable();
            let mut taken = vec![false; l.len()];
            let mut mine = vec![];
            for (r, a, b) in cand {
                if !taken[a] && !taken[b] {
                    taken[a] = true;
                    taken[b] = true;
                    used[r] += 1;
                    mine.push((r, a, b));
                }
            }
            chosen.push(mine);
        }
        // Pairs that ended up in too few rows are not worth their definition.
        let mut id = vec![u32::MAX; ranked.len()];
        let before = pairs.len();
        for (r, &u) in used.iter().enumerate() {
            if u >= min_rows {
                id[r] = (nb + pairs.len()) as u32;
                pairs.push(ranked[r].0);
            }
        }
        if pairs.len() == before {
            break;
        }
        for (l, mine) in lists.iter_mut().zip(&chosen) {
            let mut keep = vec![true; l.len()];
            let mut out = vec![];
            for &(r, a, b) in mine {
                if id[r] != u32::MAX {
                    keep[a] = false;
                    keep[b] = false;
                    out.push(id[r]);
                }
            }
            out.extend(l.iter().zip(&keep).filter(|(_, &k)| k).map(|(&x, _)| x));
            out.sort_unstable();
            *l = out;
        }
    }
    let mut ptr = vec![0u32];
    let mut ids = vec![];
    for l in &lists {
        ids.extend_from_slice(l);
        ptr.push(ids.len() as u32);
    }
    Paired { pairs, ptr, ids }
}

/// The prototype gather of the paired form, one thread: per block, pass 1 (as the library's),
/// the pairs in order, then each row's sum of its (shorter) list.
fn paired_gather(v: &BiclusterView<'_>, blocks: &[Paired], lp: &[[f32; 3]], out: &mut [[f32; 3]]) {
    let mut a: Vec<[f32; 3]> = vec![];
    for (blk, p) in blocks.iter().enumerate() {
        a.clear();
        for b in v.block_bc_base[blk] as usize..v.block_bc_base[blk + 1] as usize {
            let (ks, ts) = v.bicluster(b);
            let mut acc = [0.0f32; 3];
            for (&k, &t) in ks.iter().zip(ts) {
                let l = lp[k as usize];
                let t = t as f32;
                for c in 0..3 {
                    acc[c] += t * l[c];
                }
            }
            a.push(acc);
        }
        for &(x, y) in &p.pairs {
            let (x, y) = (a[x as usize], a[y as usize]);
            a.push([x[0] + y[0], x[1] + y[1], x[2] + y[2]]);
        }
        let first = blk * v.block_rows;
        for (j, w) in p.ptr.windows(2).enumerate() {
            let mut acc = [0.0f32; 3];
            for &id in &p.ids[w[0] as usize..w[1] as usize] {
                let x = a[id as usize];
                for c in 0..3 {
                    acc[c] += x[c];
                }
            }
            out[first + j] = acc;
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = <Args as clap::Parser>::parse();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    for path in &args.forms {
        let form = CompressedForm::load(path)?;
        let v = BiclusterView::new(&form)?;
        let start = Instant::now();
        let mut blocks = vec![];
        let (mut before, mut after, mut defs) = (0usize, 0usize, 0usize);
        for blk in 0..v.block_bc_base.len() - 1 {
            let base = v.block_bc_base[blk] as usize;
            let nb = v.block_bc_base[blk + 1] as usize - base;
            let rows = blk * v.block_rows..((blk + 1) * v.block_rows).min(v.rows);
            let lists: Vec<Vec<u32>> = rows
                .map(|i| {
                    let mut l: Vec<u32> = v.row_biclusters(i).map(|b| (b - base) as u32).collect();
                    l.sort_unstable();
                    l
                })
                .collect();
            before += lists.iter().map(Vec::len).sum::<usize>();
            let p = pair_block(lists, nb, args.rounds, args.min_rows);
            after += p.ids.len();
            defs += p.pairs.len();
            blocks.push(p);
        }
        let pairing_s = start.elapsed().as_secs_f64();
        println!(
            "{}: {} biclusters, {} row-list entries -> {} + {} pairs ({} operand entries): {:.3} of the entries \
             ({:.3} counting each pair's two operands); pairing took {:.1} s",
            path.display(),
            v.biclusters(),
            before,
            after,
            defs,
            2 * defs,
            after as f64 / before as f64,
            (after + 2 * defs) as f64 / before as f64,
            pairing_s
        );
        // The two gathers agree to f32 rounding (the sums are reassociated), then time them.
        let res = form.light_basis().cubemap_layout().ok_or("not a cubemap-light form")?.resolution;
        let light = random_light(res, 1);
        let inv_q = 1.0 / v.value_scale as f32;
        let lp: Vec<[f32; 3]> = light.power.iter().map(|p| p.map(|x| x * inv_q)).collect();
        let compressor = registry::build(&form.kind, &serde_json::json!({}))?;
        let plain = pool.install(|| compressor.gather(&form, &light))?;
        let mut out = vec![[0.0f32; 3]; v.rows];
        paired_gather(&v, &blocks, &lp, &mut out);
        let plain64: Vec<[f64; 3]> = plain.values().iter().map(|v| v.map(f64::from)).collect();
        let rel = relative_l2_error(&out, &plain64);
        if rel > 1e-5 {
            return Err(format!("{}: the paired gather differs from the plain one by {rel:.2e}", path.display()).into());
        }
        let (mut tp, mut tq) = (vec![], vec![]);
        for _ in 0..args.timing_rounds.max(1) {
            let t = Instant::now();
            std::hint::black_box(pool.install(|| compressor.gather(&form, &light))?);
            tp.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            paired_gather(&v, &blocks, &lp, &mut out);
            std::hint::black_box(&out);
            tq.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let (p, q) = (median(&tp), median(&tq));
        println!(
            "    1 thread, medians of {}: library gather {p:.3} ms, paired prototype {q:.3} ms ({:.2}x); \
             relative difference {rel:.1e}",
            tp.len(),
            p / q
        );
    }
    Ok(())
}
