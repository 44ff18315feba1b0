//! The comparisons of the biclustering paper, computed from a run's records: which setting
//! of each lossy compressor matches a storage budget ("equal storage", the paper's Figure 6),
//! and how much storage each lossy compressor needs to reach an error target ("equal
//! quality", the comparison the paper could not make because CPCA took 10 hours to build).

use crate::metrics::CompressorRecord;
use std::collections::BTreeMap;

/// For every compressor kind, the setting whose storage is closest to `target_bytes`
/// (closest in log ratio, so 2x too big and 2x too small count the same).
pub fn equal_storage<'a>(
    records: impl IntoIterator<Item = &'a CompressorRecord>,
    target_bytes: u64,
) -> Vec<&'a CompressorRecord> {
    let mut best: BTreeMap<String, &CompressorRecord> = BTreeMap::new();
    let dist = |r: &CompressorRecord| ((r.bytes.max(1) as f64) / (target_bytes.max(1) as f64)).ln().abs();
    for r in records {
        let e = best.entry(series_of(r)).or_insert(r);
        if dist(r) < dist(e) {
            *e = r;
        }
    }
    best.into_values().collect()
}

/// Storage needed to reach `target_error` along one compressor's sweep.
#[derive(Clone, Debug, PartialEq)]
pub enum StorageForError {
    /// The cheapest swept setting already meets the target.
    AtMost { bytes: u64, setting: String },
    /// Interpolated (log-log) between two swept settings that bracket the target.
    Between { bytes: f64, below: String, above: String },
    /// No swept setting reaches the target; the best error found and its setting.
    NotReached { best_error: f64, setting: String },
}

impl StorageForError {
    /// The storage read off, in bytes: exact for `AtMost` (an upper bound), interpolated for
    /// `Between`, none when the sweep never reaches the target.
    pub fn bytes(&self) -> Option<f64> {
        match self {
            Self::AtMost { bytes, .. } => Some(*bytes as f64),
            Self::Between { bytes, .. } => Some(*bytes),
            Self::NotReached { .. } => None,
        }
    }
}

/// Where along `records` (one kind's sweep) the relative L* error first reaches
/// `target_error`, as storage. Points are taken in order of storage; the error is assumed
/// to fall with storage between neighbouring points (log-log interpolation).
pub fn storage_for_error(records: &[&CompressorRecord], target_error: f64) -> Option<StorageForError> {
    let mut pts: Vec<&CompressorRecord> = records.to_vec();
    pts.sort_by_key(|r| r.bytes);
    let first = pts.first()?;
    if first.rel_error_lstar <= target_error {
        return Some(StorageForError::AtMost { bytes: first.bytes, setting: first.name.clone() });
    }
    for w in pts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b.rel_error_lstar <= target_error {
            let (la, lb) = ((a.bytes as f64).ln(), (b.bytes as f64).ln());
            let (ea, eb) = (a.rel_error_lstar.max(1e-300).ln(), b.rel_error_lstar.max(1e-300).ln());
            let t = if (ea - eb).abs() > 0.0 { (ea - target_error.ln()) / (ea - eb) } else { 1.0 };
            return Some(StorageForError::Between {
                bytes: (la + t.clamp(0.0, 1.0) * (lb - la)).exp(),
                below: a.name.clone(),
                above: b.name.clone(),
            });
        }
    }
    let best = pts.iter().min_by(|a, b| a.rel_error_lstar.total_cmp(&b.rel_error_lstar))?;
    Some(StorageForError::NotReached { best_error: best.rel_error_lstar, setting: best.name.clone() })
}

/// The error targets of the equal-quality table: 0.1%, 1%, 10% and the run's own target,
/// in increasing order without repeats.
pub fn equal_quality_targets(target_error: f64) -> Vec<f64> {
    let mut t = vec![1e-3, 1e-2, 1e-1, target_error];
    t.sort_by(f64::total_cmp);
    t.dedup_by(|a, b| (*a / *b - 1.0).abs() < 1e-9);
    t
}

/// Records grouped by kind, in the order kinds first appear.
pub fn by_kind(records: &[CompressorRecord]) -> Vec<(String, Vec<&CompressorRecord>)> {
    let mut out: Vec<(String, Vec<&CompressorRecord>)> = vec![];
    for r in records {
        let series = series_of(r);
        match out.iter_mut().find(|(k, _)| *k == series) {
            Some((_, v)) => v.push(r),
            None => out.push((series, vec![r])),
        }
    }
    out
}

/// The series a record belongs to in the plots and the equal-storage and equal-quality
/// tables: its kind (a sweep of one kind is one curve), except for a Python compressor (kind
/// `hosted`, every Python object's kind): each object is its own series, named by the `family`
/// it declares (its record's `params.family`, so objects of one family share a curve), else by
/// its label. Two unrelated Python compressors are never joined into one line.
pub fn series_of(r: &CompressorRecord) -> String {
    if r.kind != biscale_compressors::hosted::KIND.name {
        return r.kind.clone();
    }
    match r.params.get("family").and_then(serde_json::Value::as_str) {
        Some(family) => family.to_string(),
        None => r.name.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::{ImageErrors, ImageRecord};

    /// Built-in kinds group by kind; Python compressors (all of kind `hosted`) each by their
    /// label, or by the family they declare.
    #[test]
    fn python_compressors_are_series_of_their_own() {
        let hosted = biscale_compressors::hosted::KIND.name;
        let records = [
            rec("haar", "haar-t4", 5, 0.3),
            rec("haar", "haar-t8", 9, 0.2),
            rec(hosted, "py-a", 10, 0.1),
            rec(hosted, "py-b", 20, 0.2),
        ];
        let groups: Vec<(String, usize)> = by_kind(&records).into_iter().map(|(k, v)| (k, v.len())).collect();
        assert_eq!(groups, [("haar".into(), 2), ("py-a".into(), 1), ("py-b".into(), 1)]);
        assert_eq!(equal_storage(&records, 10).len(), 3, "one pick per series");
        let mut family = [rec(hosted, "py-a", 10, 0.1), rec(hosted, "py-b", 20, 0.2)];
        for r in &mut family {
            r.params = serde_json::json!({"python_class": "Mine", "family": "learned"});
        }
        let groups: Vec<(String, usize)> = by_kind(&family).into_iter().map(|(k, v)| (k, v.len())).collect();
        assert_eq!(groups, [("learned".into(), 2)]);
    }

    fn rec(kind: &str, name: &str, bytes: u64, err: f64) -> CompressorRecord {
        let e = ImageErrors { rmse: 0.0, psnr: 0.0, rel_l2: 0.0, ldr_psnr: 0.0, ssim: 0.0, flip: 0.0 };
        CompressorRecord {
            name: name.into(),
            kind: kind.into(),
            params: serde_json::json!({}),
            lossless: err == 0.0,
            bytes,
            bytes_by_array: Default::default(),
            bytes_per_nnz: 0.0,
            flops_per_gather: 0,
            build_seconds: 0.0,
            cached: false,
            gather_ms: 0.0,
            shade_ms: 0.0,
            gather_timing: None,
            shade_timing: None,
            rel_error_lstar: err,
            image: ImageRecord {
                vs_uncompressed: e,
                vs_reference: None,
                png: String::new(),
                exr: String::new(),
                error_png: None,
                error_scale: None,
                error_max: None,
            },
            stats: None,
            gpu: None,
        }
    }

    #[test]
    fn equal_storage_picks_the_closest_in_log_ratio() {
        let rs = vec![
            rec("haar", "h6", 50, 0.5),
            rec("haar", "h12", 100, 0.3),
            rec("haar", "h24", 400, 0.1),
            rec("cpca", "c", 1000, 0.2),
        ];
        let picked = equal_storage(&rs, 180);
        let names: Vec<&str> = picked.iter().map(|r| r.name.as_str()).collect();
        // 180/100 = 1.8, 400/180 = 2.2: h12 is closer.
        assert_eq!(names, vec!["c", "h12"]);
    }

    #[test]
    fn storage_for_error_interpolates_log_log() {
        let rs = [rec("haar", "a", 100, 0.4), rec("haar", "b", 400, 0.1)];
        let refs: Vec<&CompressorRecord> = rs.iter().collect();
        // log-linear halfway in error (0.2 = geometric mean of 0.4 and 0.1) is halfway in
        // log storage: 200 bytes.
        match storage_for_error(&refs, 0.2).unwrap() {
            StorageForError::Between { bytes, below, above } => {
                assert!((bytes - 200.0).abs() < 1e-9, "{bytes}");
                assert_eq!((below.as_str(), above.as_str()), ("a", "b"));
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(storage_for_error(&refs, 0.5).unwrap(), StorageForError::AtMost { bytes: 100, setting: "a".into() });
        assert_eq!(
            storage_for_error(&refs, 0.01).unwrap(),
            StorageForError::NotReached { best_error: 0.1, setting: "b".into() }
        );
        assert!(storage_for_error(&[], 0.1).is_none());
    }

    #[test]
    fn equal_quality_targets_are_sorted_without_repeats() {
        assert_eq!(equal_quality_targets(0.05), vec![1e-3, 1e-2, 0.05, 1e-1]);
        assert_eq!(equal_quality_targets(0.01), vec![1e-3, 1e-2, 1e-1]);
    }
}
