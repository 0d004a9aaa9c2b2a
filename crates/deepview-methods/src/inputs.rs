//! Which views are a method's inputs: one rule for every command that makes an MPI (`infer`, `eval`, the
//! demo), with one default.

use crate::error::MethodError;
use deepview_geometry::{Camera, DVec3};
use std::fmt;
use std::str::FromStr;

/// Which views are the inputs of an MPI. The spellings (`--inputs`):
/// - `nearest:K`: the K views whose camera centres are nearest the target's (in `eval`, each scored
///   target, the other targets left out); where there is no target (`infer`), nearest the centroid of all
///   camera centres, as `centroid:K`. **The default, with K = 4** (or the count the learned weights were
///   trained for, see [`InputRule::default_for`]).
/// - `nearest:K@V`: the K views nearest view V (V itself included unless it is a target).
/// - `centroid:K`: the K views nearest the centroid of all camera centres.
/// - `all`: every view (in `eval`, every non-target view).
/// - `3,0,5`: these views.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum InputRule {
    /// `nearest:K`: nearest the target, or the centroid where there is none.
    Nearest(usize),
    /// `nearest:K@V`: nearest view `view`.
    NearestTo { count: usize, view: usize },
    /// `centroid:K`: nearest the centroid of all camera centres.
    Centroid(usize),
    /// `spread:K`: K views spread evenly over the others in index order (`cand[round(i)]` for `i` in
    /// `linspace(0, len - 1, K)`), the same for every target: with targets `every:8`, the few-shot
    /// protocol of RegNeRF, FreeNeRF and FSGS (`spread:3`).
    Spread(usize),
    /// `all`: every view that is not a target.
    All,
    /// The same explicit views for every target.
    List(Vec<usize>),
}

/// What `--inputs` accepts, for error messages.
pub const INPUT_RULES: &str =
    "nearest:K, nearest:K@VIEW, centroid:K, spread:K, all, or a list of view indices like 0,3,5";

/// The input count of the default rule for methods that take any number of views.
pub const DEFAULT_INPUTS: usize = 4;

impl Default for InputRule {
    fn default() -> Self {
        Self::Nearest(DEFAULT_INPUTS)
    }
}

impl InputRule {
    /// The default rule for a method that needs exactly `views` inputs (`None`: any number):
    /// `nearest:K` with that count, [`DEFAULT_INPUTS`] otherwise.
    pub fn default_for(views: Option<usize>) -> Self {
        Self::Nearest(views.unwrap_or(DEFAULT_INPUTS))
    }

    /// The inputs this rule picks among `cameras` for the view with index `target` (`None`: there is no
    /// target), never picking a view of `exclude` (the other targets) except through an explicit list.
    /// Order: a list as given; nearest a view by distance (ties: the lower index); the others ascending.
    pub fn select(
        &self,
        cameras: &[Camera],
        target: Option<usize>,
        exclude: &[usize],
    ) -> Result<Vec<usize>, MethodError> {
        let n = cameras.len();
        let check = |i: usize| -> Result<usize, MethodError> {
            if i < n {
                Ok(i)
            } else {
                Err(MethodError::ViewIndex { index: i, views: n })
            }
        };
        let candidates = || -> Vec<usize> {
            (0..n)
                .filter(|i| !exclude.contains(i) && Some(*i) != target)
                .collect()
        };
        let enough = |cand: &[usize], k: usize| -> Result<(), MethodError> {
            if cand.len() < k {
                return Err(MethodError::TooFewViews {
                    rule: self.to_string(),
                    wanted: k,
                    available: cand.len(),
                });
            }
            Ok(())
        };
        let nearest = |anchor: DVec3, k: usize| -> Result<Vec<usize>, MethodError> {
            let mut cand = candidates();
            enough(&cand, k)?;
            cand.sort_by(|&a, &b| {
                let (da, db) = (
                    cameras[a].center().distance(anchor),
                    cameras[b].center().distance(anchor),
                );
                da.total_cmp(&db).then(a.cmp(&b))
            });
            cand.truncate(k);
            Ok(cand)
        };
        let centroid = |k: usize| -> Result<Vec<usize>, MethodError> {
            if n == 0 {
                return Err(MethodError::TooFewViews {
                    rule: self.to_string(),
                    wanted: k,
                    available: 0,
                });
            }
            let c = cameras.iter().fold(DVec3::ZERO, |a, c| a + c.center()) / n as f64;
            let mut picked = nearest(c, k)?;
            picked.sort_unstable();
            Ok(picked)
        };
        match self {
            InputRule::Nearest(k) => match target {
                Some(t) => nearest(cameras[check(t)?].center(), *k),
                None => centroid(*k),
            },
            InputRule::NearestTo { count, view } => {
                nearest(cameras[check(*view)?].center(), *count)
            }
            InputRule::Centroid(k) => centroid(*k),
            InputRule::Spread(k) => {
                let cand = candidates();
                enough(&cand, *k)?;
                Ok(spread(&cand, *k))
            }
            InputRule::All => {
                let cand = candidates();
                enough(&cand, 1)?;
                Ok(cand)
            }
            InputRule::List(v) => {
                for &i in v {
                    check(i)?;
                    if Some(i) == target {
                        return Err(MethodError::BadRule {
                            rule: self.to_string(),
                            msg: format!("target view {i} is also an input"),
                        });
                    }
                }
                Ok(v.clone())
            }
        }
    }
}

/// `k` of `cand` spread evenly: `cand[round(i)]` for `i` in `linspace(0, len - 1, k)` (numpy's rounding,
/// half to even); `k <= cand.len()`.
fn spread(cand: &[usize], k: usize) -> Vec<usize> {
    let last = (cand.len() - 1) as f64;
    (0..k)
        .map(|j| {
            let x = if k == 1 {
                0.0
            } else {
                last * j as f64 / (k - 1) as f64
            };
            cand[(x.round_ties_even() as usize).min(cand.len() - 1)]
        })
        .collect()
}

/// A comma-separated list of view indices, no duplicates.
pub fn parse_list(rule: &str) -> Result<Vec<usize>, MethodError> {
    let bad = |msg: String| MethodError::BadRule {
        rule: rule.into(),
        msg,
    };
    let list: Vec<usize> = rule
        .split(',')
        .map(|s| {
            s.trim()
                .parse::<usize>()
                .map_err(|_| bad(format!("'{}' is not a view index", s.trim())))
        })
        .collect::<Result<_, _>>()?;
    for (k, i) in list.iter().enumerate() {
        if list[..k].contains(i) {
            return Err(bad(format!("view {i} is listed twice")));
        }
    }
    Ok(list)
}

/// `prefix` and a positive count (`nearest:4`), `None` when `rule` does not start with `prefix`.
pub fn parse_count(rule: &str, prefix: &str) -> Result<Option<usize>, MethodError> {
    match rule.strip_prefix(prefix) {
        None => Ok(None),
        Some(n) => positive(rule, n).map(Some),
    }
}

fn positive(rule: &str, n: &str) -> Result<usize, MethodError> {
    match n.trim().parse::<usize>() {
        Ok(n) if n > 0 => Ok(n),
        _ => Err(MethodError::BadRule {
            rule: rule.into(),
            msg: format!("'{n}' is not a positive count"),
        }),
    }
}

impl FromStr for InputRule {
    type Err = MethodError;
    fn from_str(s: &str) -> Result<Self, MethodError> {
        let t = s.trim();
        let with_rules = |e: MethodError| match e {
            MethodError::BadRule { rule, msg } => MethodError::BadRule {
                rule,
                msg: format!("{msg} (expected {INPUT_RULES})"),
            },
            e => e,
        };
        if t.eq_ignore_ascii_case("all") {
            return Ok(InputRule::All);
        }
        if let Some(rest) = t.strip_prefix("nearest:") {
            return match rest.split_once('@') {
                Some((k, v)) => Ok(InputRule::NearestTo {
                    count: positive(s, k).map_err(with_rules)?,
                    view: v.trim().parse().map_err(|_| {
                        with_rules(MethodError::BadRule {
                            rule: s.into(),
                            msg: format!("'{}' is not a view index", v.trim()),
                        })
                    })?,
                }),
                None => Ok(InputRule::Nearest(positive(s, rest).map_err(with_rules)?)),
            };
        }
        if let Some(k) = parse_count(t, "centroid:").map_err(with_rules)? {
            return Ok(InputRule::Centroid(k));
        }
        if let Some(k) = parse_count(t, "spread:").map_err(with_rules)? {
            return Ok(InputRule::Spread(k));
        }
        parse_list(t).map(InputRule::List).map_err(with_rules)
    }
}

pub fn join(v: &[usize]) -> String {
    v.iter()
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

impl fmt::Display for InputRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InputRule::Nearest(n) => write!(f, "nearest:{n}"),
            InputRule::NearestTo { count, view } => write!(f, "nearest:{count}@{view}"),
            InputRule::Centroid(n) => write!(f, "centroid:{n}"),
            InputRule::Spread(n) => write!(f, "spread:{n}"),
            InputRule::All => f.write_str("all"),
            InputRule::List(v) => f.write_str(&join(v)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deepview_geometry::{DMat3, Intrinsics, Pose};

    fn line(n: usize) -> Vec<Camera> {
        (0..n)
            .map(|i| {
                Camera::new(
                    8,
                    8,
                    Intrinsics::new(8.0, 8.0, 4.0, 4.0),
                    Pose::from_center(DMat3::IDENTITY, DVec3::new(i as f64, 0.0, 0.0)),
                )
            })
            .collect()
    }

    #[test]
    fn spellings_round_trip() {
        for s in [
            "nearest:4",
            "nearest:3@7",
            "centroid:2",
            "spread:3",
            "all",
            "3,0,5",
        ] {
            assert_eq!(s.parse::<InputRule>().unwrap().to_string(), s);
        }
        assert_eq!(InputRule::default().to_string(), "nearest:4");
        assert_eq!(InputRule::default_for(Some(5)), InputRule::Nearest(5));
        for bad in [
            "nearest:0",
            "nearest:x",
            "nearest:2@x",
            "centroid:",
            "1,1",
            "0,a",
            "",
        ] {
            let e = bad.parse::<InputRule>().unwrap_err().to_string();
            assert!(e.contains("centroid:K") && e.contains("all"), "{bad}: {e}");
        }
        assert!(
            "1,1"
                .parse::<InputRule>()
                .unwrap_err()
                .to_string()
                .contains("twice")
        );
        assert!(
            "0,a"
                .parse::<InputRule>()
                .unwrap_err()
                .to_string()
                .contains("not a view index")
        );
    }

    #[test]
    fn selection() {
        let cams = line(9);
        let sel = |rule: &str, target, exclude: &[usize]| {
            rule.parse::<InputRule>()
                .unwrap()
                .select(&cams, target, exclude)
        };
        // Without a target, nearest:K is centroid:K (ascending).
        assert_eq!(sel("nearest:3", None, &[]).unwrap(), [3, 4, 5]);
        assert_eq!(sel("centroid:4", None, &[]).unwrap(), [2, 3, 4, 5]);
        // With a target: by distance, ties to the lower index, targets left out.
        assert_eq!(sel("nearest:3", Some(4), &[4, 5]).unwrap(), [3, 2, 6]);
        assert_eq!(sel("nearest:2@8", None, &[]).unwrap(), [8, 7]);
        assert_eq!(
            sel("all", Some(0), &[0, 8]).unwrap(),
            (1..8).collect::<Vec<_>>()
        );
        assert_eq!(sel("5,1", None, &[]).unwrap(), [5, 1]);
        // spread:3, the few-shot protocol: 20 views, targets 0, 8, 16; train = the 17 others;
        // linspace(0, 16, 3) = 0, 8, 16 -> train[0], train[8], train[16] = 1, 10, 19.
        let cams20 = line(20);
        let few = "spread:3"
            .parse::<InputRule>()
            .unwrap()
            .select(&cams20, Some(8), &[0, 8, 16])
            .unwrap();
        assert_eq!(few, [1, 10, 19]);
        // 34 views (flower): targets 0, 8, ..., 32 (5); train 29; linspace(0, 28, 3) = 0, 14, 28.
        let cams34 = line(34);
        let targets: Vec<usize> = (0..34).filter(|i| i % 8 == 0).collect();
        let few = "spread:3"
            .parse::<InputRule>()
            .unwrap()
            .select(&cams34, Some(0), &targets)
            .unwrap();
        let train: Vec<usize> = (0..34).filter(|i| i % 8 != 0).collect();
        assert_eq!(few, [train[0], train[14], train[28]]);
        // Half-way ties round to even, as numpy does: 4 of 6 -> linspace(0, 5, 4) = 0, 1.67, 3.33, 5.
        assert_eq!(sel("spread:4", None, &[]).unwrap().len(), 4);
        assert_eq!(spread(&[10, 11, 12, 13, 14, 15], 4), [10, 12, 13, 15]);
        assert_eq!(spread(&[10, 11, 12, 13, 14], 2), [10, 14]);
        assert!(sel("spread:10", None, &[]).is_err());
        let e = sel("4,9", None, &[]).unwrap_err().to_string();
        assert!(
            e.contains("view index 9 out of range") && e.contains("9 views"),
            "{e}"
        );
        assert!(sel("nearest:10", None, &[]).is_err());
        assert!(
            sel("1,3", Some(3), &[])
                .unwrap_err()
                .to_string()
                .contains("also an input")
        );
    }
}
