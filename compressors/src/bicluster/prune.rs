//! The lossy mode of biclustering: drop biclusters from a block's exact decomposition
//! `T_block = sum_b B_b` while the error stays within a budget.
//!
//! **The norm.** The budget `beta` bounds the relative Frobenius error of `T`,
//! `||T - T'||_F <= beta ||T||_F`. It is the norm that bounds `L*` for every light at once in
//! the mean: for a sun of power `P` in a random texel k, `E ||(T - T') L||^2 = P^2 / N
//! ||T - T'||_F^2` (and the same for `T`), so the expected relative `L*` error under a sun
//! anywhere is exactly the Frobenius one. It is light-independent, so the form still
//! relights, and it never trusts smooth light to cancel errors that a sun would expose. The
//! relative `L*` error under the uniform sky is reported beside it ([`super::analysis`]).
//!
//! **The mechanism** (see `examples/lossy_bicluster_bench.rs` for the alternatives measured):
//! every bicluster `b` costs `bytes(b) = 2 r + 3 l + 4` of the form (a u16 row id per row,
//! a u16 column and an i8 code per column, a u32 offset) and dropping it adds `B_b` to the
//! error matrix `E`, raising `||E||_F^2` by `d(b) = sum_{j in R, k in K} (2 E_jk t_k + t_k^2)`
//! (integer codes: exact). A lazy greedy takes the bicluster of smallest `d(b) / bytes(b)`
//! (`d` is re-evaluated when popped, because earlier drops in the same entries change it; a
//! negative `d` is a correction whose drop cancels earlier error) and stops at the first one
//! that would take `||E||_F^2` past the block's share of the budget.
//!
//! **Blocks.** Blocks hold disjoint rows, so `||E||_F^2` is the sum of the blocks' errors:
//! a block of energy `||T_b||_F^2` gets `beta^2 ||T_b||_F^2`, and the whole form then meets
//! `beta` exactly (in integer arithmetic, whatever the thread count).

use super::greedy::Bc;
use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

/// What pruning one block did, in squared integer codes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pruned {
    /// `||E||_F^2` of the dropped biclusters (codes squared).
    pub error2: u64,
    /// `||T_block||_F^2` (codes squared).
    pub energy2: u64,
    /// Biclusters dropped.
    pub dropped: usize,
}

/// Form bytes one bicluster costs (row ids at u16, its columns, codes and offset).
fn bytes(bc: &Bc) -> f64 {
    (2 * bc.rows.len() + 3 * bc.cols.len() + 4) as f64
}

/// A heap entry: the ratio `d / bytes` the bicluster had when pushed, smallest first, ties by id.
#[derive(Clone, Copy, PartialEq)]
struct Key(f64, usize);

impl Eq for Key {}

impl Ord for Key {
    fn cmp(&self, o: &Self) -> Ordering {
        self.0.total_cmp(&o.0).then(self.1.cmp(&o.1))
    }
}

impl PartialOrd for Key {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// The error matrix `E` of one block: per block-local row, its non-zero `(column, code)`s.
struct ErrorRows(Vec<Vec<(u16, i32)>>);

impl ErrorRows {
    fn get(&self, j: u32, k: u16) -> i64 {
        self.0[j as usize].iter().find(|e| e.0 == k).map_or(0, |e| e.1 as i64)
    }

    /// `d(b)`: how much dropping `bc` raises `||E||_F^2`.
    fn delta(&self, bc: &Bc) -> i64 {
        let mut d = 0i64;
        for &j in &bc.rows {
            for (&k, &t) in bc.cols.iter().zip(&bc.vals) {
                let t = t as i64;
                d += 2 * self.get(j, k) * t + t * t;
            }
        }
        d
    }

    fn add(&mut self, bc: &Bc) {
        for &j in &bc.rows {
            let row = &mut self.0[j as usize];
            for (&k, &t) in bc.cols.iter().zip(&bc.vals) {
                match row.iter_mut().find(|e| e.0 == k) {
                    Some(e) => e.1 += t as i32,
                    None => row.push((k, t as i32)),
                }
            }
        }
    }
}

/// Drop biclusters of one block (rows `0..rows`, energy `energy2` in codes squared) while
/// `||E||_F^2 <= beta^2 energy2`; the kept ones stay in their order.
pub fn prune(bcs: Vec<Bc>, rows: usize, energy2: u64, beta: f64) -> (Vec<Bc>, Pruned) {
    let mut out = Pruned { energy2, ..Pruned::default() };
    // The largest integer error allowed; f64 is exact for any energy a u32-row block holds
    // (< 2^53), and flooring keeps the bound on the safe side.
    let allowed = (beta * beta * energy2 as f64).floor().min(energy2 as f64) as i64;
    if allowed <= 0 || bcs.is_empty() {
        return (bcs, out);
    }
    let mut err = ErrorRows(vec![Vec::new(); rows]);
    let mut heap: BinaryHeap<Reverse<Key>> =
        bcs.iter().enumerate().map(|(i, bc)| Reverse(Key(err.delta(bc) as f64 / bytes(bc), i))).collect();
    let mut keep = vec![true; bcs.len()];
    let mut error2 = 0i64;
    while let Some(Reverse(Key(stored, i))) = heap.pop() {
        let d = err.delta(&bcs[i]);
        let now = d as f64 / bytes(&bcs[i]);
        // Lazy re-evaluation: a key that got worse goes back unless it still beats the rest.
        if now > stored && heap.peek().is_some_and(|top| now > top.0 .0) {
            heap.push(Reverse(Key(now, i)));
            continue;
        }
        if error2 + d > allowed {
            break;
        }
        error2 += d;
        err.add(&bcs[i]);
        keep[i] = false;
        out.dropped += 1;
    }
    out.error2 = error2 as u64;
    let kept = bcs.into_iter().zip(keep).filter_map(|(bc, k)| k.then_some(bc)).collect();
    (kept, out)
}
