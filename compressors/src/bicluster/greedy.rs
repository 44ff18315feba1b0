//! The greedy constant-column biclustering of one block of rows (Sun et al., Algorithm 1),
//! with the published speed-up: every candidate row and column operation sits in a priority
//! queue keyed by its influence, and an operation updates only the entries it touches.
//!
//! Notation (paper, section 4): the current matrix `T_c` starts as the block of `T` (integer
//! codes) and loses each emitted bicluster `B` (rows `R`, columns `k_m` with constants `t_m`).
//! For the submatrix `M` of `T_c` that `B` covers, `dW(M) = 2 nnz(M) - (r + 2l - 1) - 2 nnz(M_R)`
//! with `M_R = M - B`: an element contributes +2 when it equals its column's constant, -2
//! when it is zero (the residual `-t` becomes a new non-zero), 0 for a different non-zero;
//! each row costs 1 and each column 2 ([`Costs`]: the column's cost is a parameter, written
//! `wc` below; the paper's is 2).
//!
//! Incremental form used here. For a row `j` let `m_j` (`o_j`) count `B`'s columns where
//! `T_c[j, k] = t_k` (`!= t_k`, non-zero); the row's contribution is
//! `2 m_j - 2 (l - m_j - o_j) - 1 = (4 m_j + 2 o_j) - 2l - 1`, so the row key `4 m_j + 2 o_j`
//! changes only when a column of `B` is inserted or deleted in which row `j` has a non-zero.
//! For a column `k` let `c_k(v)` count `B`'s rows with `T_c[j, k] = v` and `n_k` the non-zeros;
//! with constant `t` its contribution is `2 c_k(t) - 2 (r - n_k) - wc = 2 (c_k(t) + n_k) - 2r - wc`,
//! so the column key `c_k(t) + n_k` (with `t` the most frequent non-zero for candidates, the
//! fixed constant for members) changes only when a row with a non-zero in `k` is inserted or
//! deleted. Four lazy heaps (row insert/delete, column insert/delete) hold keys; stale
//! entries are skipped by re-checking the key. Each step applies the operation of largest
//! gain and stops when none is positive, so `dW` ends at least the seed element's
//! `2 - (1 + wc - 1)`, and above it unless `B` is the seed alone. Then
//! `nnz(M) - nnz(M_R) = (dW + W(B)) / 2 >= 1`: `nnz(T_c)` strictly drops, and the loop ends
//! with `T_c = 0`.

use super::codes::{CodeMatrix, CODE_MAX};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Column constant marker for "not in B".
const NOT_IN_B: i16 = i16::MIN;

/// One non-zero of `T_c`: column, code, and its position in the column view.
#[derive(Clone, Copy, Debug)]
struct Entry {
    col: u16,
    code: i8,
    pos: u32,
}

/// One emitted bicluster: block-local rows (increasing), columns (increasing) and their
/// constant codes.
#[derive(Clone, Debug, PartialEq)]
pub struct Bc {
    pub rows: Vec<u32>,
    pub cols: Vec<u16>,
    pub vals: Vec<i8>,
}

/// Per-column state of the current bicluster, packed so one cache line serves an update.
#[derive(Clone, Copy, Debug)]
struct ColState {
    /// Non-zeros `n_k` of the column among B's rows.
    nnz: u32,
    /// `max_v c_k(v)` and its value (the constant a candidate column would take).
    best_cnt: u32,
    /// Position in B's column list.
    pos: u32,
    /// Constant of the column when it is in B, else `NOT_IN_B`.
    t: i16,
    best_code: i8,
}

const COL_CLEAN: ColState = ColState { nnz: 0, best_cnt: 0, pos: 0, t: NOT_IN_B, best_code: 0 };

/// Per-thread scratch over the columns, clean (all zero, empty views) between blocks.
pub struct Workspace {
    cols: Vec<ColState>,
    /// `c_k(v)` for codes `v` in the window `[-win/2, win/2)`: `counts[k * win + v + win/2]`.
    counts: Vec<u32>,
    win: usize,
    /// `c_k(v)` for codes outside the window (rare: deep residuals), keyed by `(k, v)`.
    overflow: std::collections::HashMap<(u16, i8), u32>,
    /// Column view of `T_c`: the (row, code) pairs of its non-zeros, in no order.
    colview: Vec<Vec<(u32, i8)>>,
}

impl Workspace {
    /// Scratch for `ncols` columns of a matrix whose codes are at most `max_code` in size.
    pub fn new(ncols: usize, max_code: i32) -> Self {
        // Residuals of codes in [-c, c] mostly stay in [-2c, 2c]: a window of that width
        // catches nearly every update, the overflow map the rest.
        let win = ((4 * max_code.max(1) + 2) as usize).next_power_of_two().clamp(16, 256);
        Self {
            cols: vec![COL_CLEAN; ncols],
            counts: vec![0; ncols * win],
            win,
            overflow: Default::default(),
            colview: vec![Vec::new(); ncols],
        }
    }

    #[inline]
    fn count(&self, k: usize, v: i8) -> u32 {
        let s = v as i32 + (self.win / 2) as i32;
        if s >= 0 && (s as usize) < self.win {
            self.counts[k * self.win + s as usize]
        } else {
            self.overflow.get(&(k as u16, v)).copied().unwrap_or(0)
        }
    }

    #[inline]
    fn count_mut(&mut self, k: usize, v: i8) -> &mut u32 {
        let s = v as i32 + (self.win / 2) as i32;
        if s >= 0 && (s as usize) < self.win {
            &mut self.counts[k * self.win + s as usize]
        } else {
            self.overflow.entry((k as u16, v)).or_insert(0)
        }
    }

    /// The most frequent value of column `k` and its count (the first in window order,
    /// then the overflow values in code order, on ties).
    fn rescan_best(&self, k: usize) -> (u32, i8) {
        let base = k * self.win;
        let mut best = (0u32, 0i8);
        for s in 0..self.win {
            if self.counts[base + s] > best.0 {
                best = (self.counts[base + s], (s as i32 - (self.win / 2) as i32) as i8);
            }
        }
        if !self.overflow.is_empty() {
            let mut extra: Vec<(i8, u32)> =
                self.overflow.iter().filter(|((kk, _), _)| *kk as usize == k).map(|(&(_, v), &c)| (v, c)).collect();
            extra.sort_unstable();
            for (v, c) in extra {
                if c > best.0 {
                    best = (c, v);
                }
            }
        }
        best
    }
}

struct Block<'w> {
    ws: &'w mut Workspace,
    rows: Vec<Vec<Entry>>,
    m: Vec<u32>,
    o: Vec<u32>,
    in_row: Vec<bool>,
    row_pos: Vec<u32>,
    brows: Vec<u32>,
    bcols: Vec<u16>,
    nonempty: Vec<u32>,
    nonempty_pos: Vec<u32>,
    max_row_len: usize,
    max_abs: i32,
    /// Max-heaps over `key << 32 | (u32::MAX - id)` (ties: smaller id first). A candidate
    /// improves `dW` only if its key beats the bar (rows `> 2l + 1`, columns `> r + wc / 2`), so
    /// only keys above a floor at most the bar are kept: every candidate whose key is above
    /// `row_floor` (`col_floor`) has a valid entry. Insertions raise the floor to
    /// `bar - FLOOR_SLACK`; a deletion that lowers the bar below the floor rebuilds the heap
    /// (rare thanks to the slack).
    row_ins: BinaryHeap<u64>,
    col_ins: BinaryHeap<u64>,
    row_floor: u64,
    col_floor: u64,
    /// Min-heaps over `key << 32 | id` (all members).
    row_del: BinaryHeap<Reverse<u64>>,
    col_del: BinaryHeap<Reverse<u64>>,
    /// Scratch row for `subtract`.
    scratch: Vec<Entry>,
    /// The cost of one row and one column of a bicluster in `dW` (the paper's: 1 and 2).
    costs: Costs,
}

/// What a bicluster's rows and columns cost in `dW = 2 nnz(M) - W(B) - 2 nnz(M_R)`,
/// `W(B) = row r + col l - 1`. The paper's flop count is `row = 1, col = 2`; the compressor
/// sets `row = 1` and `col` from its `column_cost` key ([`super::Bicluster::costs`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Costs {
    pub row: u64,
    pub col: u64,
}

/// How far below the bar the candidate heaps keep keys (see `Block::row_ins`).
const FLOOR_SLACK: u64 = 8;

impl Block<'_> {
    #[inline]
    fn row_key(&self, j: usize) -> u64 {
        4 * self.m[j] as u64 + 2 * self.o[j] as u64
    }

    #[inline]
    fn col_key_ins(&self, k: usize) -> u64 {
        let c = &self.ws.cols[k];
        c.best_cnt as u64 + c.nnz as u64
    }

    #[inline]
    fn col_key_del(&self, k: usize) -> u64 {
        let c = &self.ws.cols[k];
        self.ws.count(k, c.t as i8) as u64 + c.nnz as u64
    }

    #[inline]
    fn push_row(&mut self, j: usize) {
        let key = self.row_key(j);
        if self.in_row[j] {
            self.row_del.push(Reverse(key << 32 | j as u64));
        } else if key > self.row_floor {
            self.row_ins.push(key << 32 | (u32::MAX - j as u32) as u64);
        }
    }

    #[inline]
    fn push_col(&mut self, k: usize) {
        if self.ws.cols[k].t != NOT_IN_B {
            let key = self.col_key_del(k);
            self.col_del.push(Reverse(key << 32 | k as u64));
        } else {
            let key = self.col_key_ins(k);
            if self.ws.cols[k].best_cnt > 0 && key > self.col_floor {
                self.col_ins.push(key << 32 | (u32::MAX - k as u32) as u64);
            }
        }
    }

    fn add_col(&mut self, k: usize, t: i8) {
        self.ws.cols[k].t = t as i16;
        self.ws.cols[k].pos = self.bcols.len() as u32;
        self.bcols.push(k as u16);
        self.row_floor = self.row_floor.max((2 * self.bcols.len() as u64 + self.costs.row).saturating_sub(FLOOR_SLACK));
        for i in 0..self.ws.colview[k].len() {
            let (j, x) = self.ws.colview[k][i];
            let j = j as usize;
            if x == t {
                self.m[j] += 1;
            } else {
                self.o[j] += 1;
            }
            self.push_row(j);
        }
        self.push_col(k);
    }

    fn remove_col(&mut self, k: usize) {
        let t = self.ws.cols[k].t as i8;
        self.ws.cols[k].t = NOT_IN_B;
        let p = self.ws.cols[k].pos as usize;
        self.bcols.swap_remove(p);
        if p < self.bcols.len() {
            self.ws.cols[self.bcols[p] as usize].pos = p as u32;
        }
        for i in 0..self.ws.colview[k].len() {
            let (j, x) = self.ws.colview[k][i];
            let j = j as usize;
            if x == t {
                self.m[j] -= 1;
            } else {
                self.o[j] -= 1;
            }
            self.push_row(j);
        }
        // l dropped: if the bar fell below the floor, rows under the floor may now qualify:
        // rebuild the row candidates from every column of B (any row with a non-zero there).
        let bar = 2 * self.bcols.len() as u64 + self.costs.row;
        if bar < self.row_floor {
            self.row_floor = bar.saturating_sub(FLOOR_SLACK);
            self.row_ins.clear();
            for c in 0..self.bcols.len() {
                let kk = self.bcols[c] as usize;
                for i in 0..self.ws.colview[kk].len() {
                    let j = self.ws.colview[kk][i].0 as usize;
                    if !self.in_row[j] {
                        self.push_row(j);
                    }
                }
            }
        }
        self.push_col(k);
    }

    fn add_row(&mut self, j: usize) {
        self.in_row[j] = true;
        self.row_pos[j] = self.brows.len() as u32;
        self.brows.push(j as u32);
        self.col_floor = self.col_floor.max((self.brows.len() as u64 + self.costs.col / 2).saturating_sub(FLOOR_SLACK));
        for i in 0..self.rows[j].len() {
            let e = self.rows[j][i];
            let k = e.col as usize;
            let c = self.ws.count_mut(k, e.code);
            *c += 1;
            let c = *c;
            let st = &mut self.ws.cols[k];
            st.nnz += 1;
            if c > st.best_cnt {
                st.best_cnt = c;
                st.best_code = e.code;
            }
            self.push_col(k);
        }
        self.push_row(j);
    }

    fn remove_row(&mut self, j: usize) {
        self.in_row[j] = false;
        let p = self.row_pos[j] as usize;
        self.brows.swap_remove(p);
        if p < self.brows.len() {
            self.row_pos[self.brows[p] as usize] = p as u32;
        }
        for i in 0..self.rows[j].len() {
            let e = self.rows[j][i];
            let k = e.col as usize;
            *self.ws.count_mut(k, e.code) -= 1;
            self.ws.cols[k].nnz -= 1;
            if e.code == self.ws.cols[k].best_code {
                // The best count dropped by one; another value may now lead.
                let (c, v) = self.ws.rescan_best(k);
                self.ws.cols[k].best_cnt = c;
                self.ws.cols[k].best_code = v;
            }
            self.push_col(k);
        }
        // r dropped: if the bar fell below the floor, columns under the floor may now
        // qualify: rebuild the column candidates from every row of B.
        let bar = self.brows.len() as u64 + self.costs.col / 2;
        if bar < self.col_floor {
            self.col_floor = bar.saturating_sub(FLOOR_SLACK);
            self.col_ins.clear();
            for c in 0..self.brows.len() {
                let jj = self.brows[c] as usize;
                for i in 0..self.rows[jj].len() {
                    let k = self.rows[jj][i].col as usize;
                    if self.ws.cols[k].t == NOT_IN_B {
                        self.push_col(k);
                    }
                }
            }
        }
        self.push_row(j);
    }

    /// Best valid entry of each heap, popping stale ones.
    fn top_row_ins(&mut self) -> Option<(i64, usize)> {
        while let Some(&e) = self.row_ins.peek() {
            let (key, j) = (e >> 32, (u32::MAX - e as u32) as usize);
            if !self.in_row[j] && self.row_key(j) == key {
                return Some((key as i64, j));
            }
            self.row_ins.pop();
        }
        None
    }

    fn top_row_del(&mut self) -> Option<(i64, usize)> {
        while let Some(&Reverse(e)) = self.row_del.peek() {
            let (key, j) = (e >> 32, e as u32 as usize);
            if self.in_row[j] && self.row_key(j) == key {
                return Some((key as i64, j));
            }
            self.row_del.pop();
        }
        None
    }

    fn top_col_ins(&mut self) -> Option<(i64, usize)> {
        while let Some(&e) = self.col_ins.peek() {
            let (key, k) = (e >> 32, (u32::MAX - e as u32) as usize);
            if self.ws.cols[k].t == NOT_IN_B && self.ws.cols[k].best_cnt > 0 && self.col_key_ins(k) == key {
                return Some((key as i64, k));
            }
            self.col_ins.pop();
        }
        None
    }

    fn top_col_del(&mut self) -> Option<(i64, usize)> {
        while let Some(&Reverse(e)) = self.col_del.peek() {
            let (key, k) = (e >> 32, e as u32 as usize);
            if self.ws.cols[k].t != NOT_IN_B && self.col_key_del(k) == key {
                return Some((key as i64, k));
            }
            self.col_del.pop();
        }
        None
    }

    /// Grow a bicluster from the seed element, hill-climbing on `dW`.
    fn grow(&mut self, j0: usize, k0: usize, t0: i8) {
        self.add_col(k0, t0);
        self.add_row(j0);
        loop {
            let (r, l) = (self.brows.len() as i64, self.bcols.len() as i64);
            let (wr, wc) = (self.costs.row as i64, self.costs.col as i64);
            // (gain, op, index); ops: 0 row insert, 1 column insert, 2 row delete, 3 column delete.
            let mut best: (i64, u8, usize) = (0, 255, 0);
            if let Some((key, j)) = self.top_row_ins() {
                let g = key - 2 * l - wr;
                if g > best.0 {
                    best = (g, 0, j);
                }
            }
            if let Some((key, k)) = self.top_col_ins() {
                let g = 2 * key - 2 * r - wc;
                if g > best.0 {
                    best = (g, 1, k);
                }
            }
            if r > 1 {
                if let Some((key, j)) = self.top_row_del() {
                    let g = 2 * l + wr - key;
                    if g > best.0 {
                        best = (g, 2, j);
                    }
                }
            }
            if l > 1 {
                if let Some((key, k)) = self.top_col_del() {
                    let g = 2 * r + wc - 2 * key;
                    if g > best.0 {
                        best = (g, 3, k);
                    }
                }
            }
            match best.1 {
                0 => self.add_row(best.2),
                1 => {
                    let t = self.ws.cols[best.2].best_code;
                    self.add_col(best.2, t)
                }
                2 => self.remove_row(best.2),
                3 => self.remove_col(best.2),
                _ => break,
            }
        }
    }

    /// Clear the per-bicluster statistics (cost proportional to what B touched).
    fn reset_stats(&mut self) {
        for &j in &self.brows {
            let j = j as usize;
            self.in_row[j] = false;
            for e in &self.rows[j] {
                let k = e.col as usize;
                *self.ws.count_mut(k, e.code) = 0;
                let st = &mut self.ws.cols[k];
                st.nnz = 0;
                st.best_cnt = 0;
            }
        }
        self.ws.overflow.clear();
        for &k in &self.bcols {
            let k = k as usize;
            self.ws.cols[k].t = NOT_IN_B;
            for &(j, _) in &self.ws.colview[k] {
                self.m[j as usize] = 0;
                self.o[j as usize] = 0;
            }
        }
        self.row_ins.clear();
        self.col_ins.clear();
        self.row_del.clear();
        self.col_del.clear();
        self.row_floor = 0;
        self.col_floor = 0;
    }

    fn code_at(&self, j: usize, k: u16) -> i8 {
        let row = &self.rows[j];
        match row.binary_search_by_key(&k, |e| e.col) {
            Ok(i) => row[i].code,
            Err(_) => 0,
        }
    }

    /// Whether subtracting `B` keeps every residual code within `[-CODE_MAX, CODE_MAX]`.
    fn residuals_fit(&self, cols: &[u16], vals: &[i8]) -> bool {
        if 2 * self.max_abs <= CODE_MAX {
            return true;
        }
        self.brows.iter().all(|&j| {
            cols.iter().zip(vals).all(|(&k, &t)| (self.code_at(j as usize, k) as i32 - t as i32).abs() <= CODE_MAX)
        })
    }

    /// Remove `(j, k)` from the column view, fixing the back pointer of the element moved.
    fn colview_remove(&mut self, k: usize, pos: u32) {
        let view = &mut self.ws.colview[k];
        view.swap_remove(pos as usize);
        if (pos as usize) < view.len() {
            let (j2, _) = view[pos as usize];
            let row = &mut self.rows[j2 as usize];
            let i = row.binary_search_by_key(&(k as u16), |e| e.col).expect("column view and rows agree");
            row[i].pos = pos;
        }
    }

    /// `T_c -= B` on rows `rows`, columns `cols` with constants `vals` (both sorted).
    fn subtract(&mut self, rows: &[u32], cols: &[u16], vals: &[i8]) {
        let mut new = std::mem::take(&mut self.scratch);
        for &j in rows {
            let j = j as usize;
            // Row j's entries stay in place while the views change: the element a removal
            // moves in a column view always belongs to another row (a view holds j once).
            new.clear();
            let was_empty = self.rows[j].is_empty();
            let (mut a, mut b) = (0, 0);
            let n_old = self.rows[j].len();
            while a < n_old || b < cols.len() {
                let ka = if a < n_old { self.rows[j][a].col as u32 } else { u32::MAX };
                let kb = cols.get(b).map_or(u32::MAX, |&k| k as u32);
                if ka < kb {
                    new.push(self.rows[j][a]);
                    a += 1;
                } else if kb < ka {
                    let (k, code) = (cols[b] as usize, -vals[b]);
                    let view = &mut self.ws.colview[k];
                    view.push((j as u32, code));
                    new.push(Entry { col: k as u16, code, pos: (view.len() - 1) as u32 });
                    self.max_abs = self.max_abs.max((code as i32).abs());
                    b += 1;
                } else {
                    let e = self.rows[j][a];
                    let y = e.code as i32 - vals[b] as i32;
                    let k = e.col as usize;
                    if y == 0 {
                        self.colview_remove(k, e.pos);
                    } else {
                        self.ws.colview[k][e.pos as usize].1 = y as i8;
                        new.push(Entry { code: y as i8, ..e });
                        self.max_abs = self.max_abs.max(y.abs());
                    }
                    a += 1;
                    b += 1;
                }
            }
            self.max_row_len = self.max_row_len.max(new.len());
            let now_empty = new.is_empty();
            self.rows[j].clear();
            self.rows[j].extend_from_slice(&new);
            if was_empty && !now_empty {
                self.nonempty_pos[j] = self.nonempty.len() as u32;
                self.nonempty.push(j as u32);
            } else if !was_empty && now_empty {
                let p = self.nonempty_pos[j] as usize;
                self.nonempty.swap_remove(p);
                if p < self.nonempty.len() {
                    self.nonempty_pos[self.nonempty[p] as usize] = p as u32;
                }
            }
        }
        self.scratch = new;
    }
}

#[cfg(test)]
impl Block<'_> {
    /// `dW` of rows `rows` x columns `cols` (with constants) on `T_c`, from the definition.
    fn naive_dw(&self, rows: &[usize], cols: &[(u16, i8)]) -> i64 {
        let mut d = -(self.costs.row as i64 * rows.len() as i64 + self.costs.col as i64 * cols.len() as i64 - 1);
        for &j in rows {
            for &(k, t) in cols {
                let x = self.code_at(j, k);
                d += if x == t {
                    2
                } else if x == 0 {
                    -2
                } else {
                    0
                };
            }
        }
        d
    }

    /// The grown bicluster is a local optimum of `dW` under single row/column insertions
    /// and deletions, computed from scratch: checks the heaps and incremental keys.
    fn check_local_optimum(&self) {
        let rows: Vec<usize> = self.brows.iter().map(|&j| j as usize).collect();
        let cols: Vec<(u16, i8)> = self.bcols.iter().map(|&k| (k, self.ws.cols[k as usize].t as i8)).collect();
        let base = self.naive_dw(&rows, &cols);
        // Every step raised dW from the seed's (one element equal to its constant: 0 at the
        // paper's costs, negative when a column costs more than 2).
        let seed = 2 - (self.costs.row + self.costs.col) as i64 + 1;
        assert!(base > seed || base == seed && rows.len() * cols.len() == 1, "dW {base} of {rows:?} x {cols:?}");
        // Rows without a non-zero in B's columns only lose (-2 per column, -1 for the row),
        // and columns without a non-zero in B's rows have no value to take: skip them.
        let mut cand_rows: Vec<usize> =
            cols.iter().flat_map(|&(k, _)| self.ws.colview[k as usize].iter().map(|&(j, _)| j as usize)).collect();
        cand_rows.extend(&rows);
        cand_rows.sort_unstable();
        cand_rows.dedup();
        let mut cand_cols: Vec<u16> = rows.iter().flat_map(|&j| self.rows[j].iter().map(|e| e.col)).collect();
        cand_cols.extend(cols.iter().map(|&(k, _)| k));
        cand_cols.sort_unstable();
        cand_cols.dedup();
        for j in cand_rows {
            let mut r2 = rows.clone();
            if let Some(p) = r2.iter().position(|&x| x == j) {
                if rows.len() > 1 {
                    r2.remove(p);
                    assert!(self.naive_dw(&r2, &cols) <= base, "deleting row {j} improves dW");
                }
            } else {
                r2.push(j);
                assert!(self.naive_dw(&r2, &cols) <= base, "inserting row {j} improves dW");
            }
        }
        for k in cand_cols {
            let mut c2 = cols.clone();
            if let Some(p) = c2.iter().position(|&(x, _)| x == k) {
                if cols.len() > 1 {
                    c2.remove(p);
                    assert!(self.naive_dw(&rows, &c2) <= base, "deleting column {k} improves dW");
                }
            } else {
                let mut freq = std::collections::BTreeMap::new();
                for &j in &rows {
                    let x = self.code_at(j, k);
                    if x != 0 {
                        *freq.entry(x).or_insert(0) += 1;
                    }
                }
                if let Some(best) = freq.values().max() {
                    let v = *freq.iter().find(|(_, c)| *c == best).unwrap().0;
                    c2.push((k, v));
                    assert!(self.naive_dw(&rows, &c2) <= base, "inserting column {k} = {v} improves dW");
                }
            }
        }
    }
}

/// Bicluster rows `row_range` of `codes` until the block is zero. `seed` and `stream`
/// select the random sequence (the block index is the stream, so the result does not
/// depend on which thread runs the block). `ws` must be clean; it is left clean.
pub fn bicluster_block(
    codes: &CodeMatrix,
    row_range: std::ops::Range<usize>,
    seed: u64,
    stream: u64,
    costs: Costs,
    ws: &mut Workspace,
) -> Vec<Bc> {
    let n = row_range.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    let mut rows = Vec::with_capacity(n);
    let mut nonempty = Vec::new();
    let mut nonempty_pos = vec![u32::MAX; n];
    let (mut max_row_len, mut max_abs) = (0usize, 0i32);
    for (local, i) in row_range.enumerate() {
        let row: Vec<Entry> = codes
            .row(i)
            .map(|(k, code)| {
                let view = &mut ws.colview[k as usize];
                view.push((local as u32, code));
                max_abs = max_abs.max((code as i32).abs());
                Entry { col: k, code, pos: (view.len() - 1) as u32 }
            })
            .collect();
        if !row.is_empty() {
            nonempty_pos[local] = nonempty.len() as u32;
            nonempty.push(local as u32);
        }
        max_row_len = max_row_len.max(row.len());
        rows.push(row);
    }
    let mut b = Block {
        ws,
        rows,
        m: vec![0; n],
        o: vec![0; n],
        in_row: vec![false; n],
        row_pos: vec![0; n],
        brows: Vec::new(),
        bcols: Vec::new(),
        nonempty,
        nonempty_pos,
        max_row_len,
        max_abs,
        row_ins: BinaryHeap::new(),
        col_ins: BinaryHeap::new(),
        row_del: BinaryHeap::new(),
        col_del: BinaryHeap::new(),
        row_floor: 0,
        col_floor: 0,
        scratch: Vec::new(),
        costs,
    };
    let mut out = Vec::new();
    while !b.nonempty.is_empty() {
        // A uniformly random non-zero of T_c: a random non-empty row accepted with
        // probability len / max_row_len (rejection sampling), then the entry u < len.
        let (j0, e0) = loop {
            let j = b.nonempty[rng.gen_range(0..b.nonempty.len())] as usize;
            let u = rng.gen_range(0..b.max_row_len);
            if u < b.rows[j].len() {
                break (j, b.rows[j][u]);
            }
        };
        b.grow(j0, e0.col as usize, e0.code);
        #[cfg(test)]
        b.check_local_optimum();
        let mut rows = b.brows.clone();
        rows.sort_unstable();
        let mut cv: Vec<(u16, i8)> = b.bcols.iter().map(|&k| (k, b.ws.cols[k as usize].t as i8)).collect();
        cv.sort_unstable_by_key(|&(k, _)| k);
        let (mut cols, mut vals): (Vec<u16>, Vec<i8>) = cv.into_iter().unzip();
        let fits = b.residuals_fit(&cols, &vals);
        b.reset_stats();
        b.brows.clear();
        b.bcols.clear();
        if !fits {
            // Rare fallback: the grown bicluster would push a residual code out of i8 range;
            // emit the seed element alone (always exact: its residual is 0).
            rows = vec![j0 as u32];
            cols = vec![e0.col];
            vals = vec![e0.code];
        }
        b.subtract(&rows, &cols, &vals);
        out.push(Bc { rows, cols, vals });
    }
    out
}
