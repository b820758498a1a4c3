//! A root search of the dose along a line: the methods `line` (the adjoint's axis) and `ray`
//! (random axes, forward only, the ablation), shared by `optimize` on the skill's five
//! parameters and by `study refine` on a trajectory's residuals.
//!
//! From a point `w`, an axis `u` (the adjoint's `∂L/∂w`, normalised, or independent normal
//! draws, normalised); forward trials at `w ± a·u` for `a` in [`LINE_STEPS`] look for a sign
//! change of the signed indicator `f = target − delivered`. Once one brackets `f = 0`, the
//! Illinois variant of regula falsi ([`Illinois`]) closes on it with forward rollouts. Without a
//! bracket, the lowest-loss trial (if lower than `w`'s) becomes the new `w`.
//!
//! A caller that already knows a point on the other side of the target (a `partner`, say from a
//! global phase whose rollouts both over- and under-deliver) hands it over: the segment from
//! `w` to it is then the first bracket, closed before any axis is tried, at no cost in probes.
//!
//! Why a line: the dose is a staircase of whole grains that is flat along most directions and
//! steep where it moves (a spoon that empties over the cup still empties over it; a stream that
//! leaves the cup's opening falls off a cliff). The soft count's gradient comes from the grains
//! near an edge, so it points across it: it finds a direction in which the dose moves, but
//! neither its sign nor its step size is reliable. A bracketed root search needs neither.
//!
//! Everything outside [−1, 1] is clamped: every trial stays in the box.

use crate::util::SplitMix64;

/// The bracketing steps along the axis, in units of the box's half-width, each tried on both
/// sides (`+a` first).
pub const LINE_STEPS: [f64; 3] = [0.2, 0.4, 0.8];

/// The narrowest bracket that [`Budget::closed`] accepts: a floating-point tie.
pub const CLOSED: f64 = 1e-9;

/// How close two skills (Θ in [−1, 1]⁵) may be before `optimize`'s `line` and `ray` stop
/// telling them apart: 1 % of the box's half-width, i.e. 0.04 mm of scoop depth, 0.2° of scoop
/// angle or 0.45° of pour angle in the default ranges, about a robot arm's repeatability. A
/// bracket narrower than this has closed (chosen from the ranges, not tuned on the benchmark).
pub const SKILL_REPEATABILITY: f64 = 0.01;

/// What a rollout tells the search.
#[derive(Clone, Debug, PartialEq)]
pub struct Probe {
    /// `target − delivered`, signed.
    pub indicator: f64,
    /// The scene's loss (what "lower" means when no bracket is found).
    pub loss: f64,
    /// `∂L/∂w`, when the rollout ran the backward pass.
    pub grad: Option<Vec<f64>>,
}

/// How a search spends its budget.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    /// The compute, in forward rollouts.
    pub forward_rollouts: f64,
    /// What a gradient rollout costs, in forward rollouts (`1 + BACKWARD_COST`).
    pub gradient_cost: f64,
    /// Spend the whole budget: after a closed bracket, or where the adjoint's axis finds
    /// neither a bracket nor a lower loss, start again from the lowest-loss point so far (a new
    /// gradient there, or a random axis when the gradient would repeat itself or not fit the
    /// budget). Without it the search stops there (`study refine`'s published behaviour).
    pub restart: bool,
    /// A bracket narrower than this (Euclidean, in the parameters' units) has closed: with a dose
    /// in whole grains, a bracket that straddles a jump of several grains would otherwise take
    /// the rest of the budget to shrink onto the jump, which no restart could then improve.
    /// At least [`CLOSED`].
    pub closed: f64,
}

impl Budget {
    /// `line` as `optimize` runs it: `forward_rollouts` of compute, a backward pass at its cost,
    /// restarts until the budget is spent, and a bracket closed at [`SKILL_REPEATABILITY`].
    pub fn restarting(forward_rollouts: f64) -> Budget {
        Budget {
            forward_rollouts,
            gradient_cost: 1.0 + crate::lab::optim::report::BACKWARD_COST,
            restart: true,
            closed: SKILL_REPEATABILITY,
        }
    }
}

/// Runs the search from `start`. `known` is the start's signed indicator and loss where a
/// forward rollout there already ran (a random axis then needs no new one). `partner` is a point
/// already run and its signed indicator: where that has the other sign than `known`'s, the
/// segment between them is searched first. `adjoint` picks the axis (else random draws from
/// `rng`); `eval(w, with_grad)` runs one rollout and records it wherever the caller keeps
/// rollouts.
pub fn search(
    start: &[f64],
    known: Option<(f64, f64)>,
    partner: Option<(&[f64], f64)>,
    budget: Budget,
    adjoint: bool,
    rng: &mut SplitMix64,
    eval: &mut dyn FnMut(&[f64], bool) -> anyhow::Result<Probe>,
) -> anyhow::Result<()> {
    let limit = budget.forward_rollouts + 1e-9;
    let d = start.len();
    let mut w = start.to_vec();
    let mut spent = 0.0;
    // The signed indicator and the loss at w, once known.
    let mut here: Option<(f64, f64)> = known;
    // The lowest-loss rollout so far: (loss, w, indicator).
    let mut best: Option<(f64, Vec<f64>, f64)> = known.map(|(f, l)| (l, w.clone(), f));
    // With `restart`: the adjoint's axis at this w found nothing, so the next axis is random.
    let mut stalled = false;
    let mut probe =
        |x: &[f64], grad: bool, spent: &mut f64, best: &mut Option<(f64, Vec<f64>, f64)>| {
            let p = eval(x, grad)?;
            *spent += if grad { budget.gradient_cost } else { 1.0 };
            if best.as_ref().is_none_or(|b| p.loss < b.0) {
                *best = Some((p.loss, x.to_vec(), p.indicator));
            }
            anyhow::Ok(p)
        };
    let closed = budget.closed.max(CLOSED);
    // A bracket known before any probe: the segment from w to the partner, as the axis x − w
    // left unnormalised, so that [0, 1] spans it.
    let mut segment: Option<(Vec<f64>, f64)> = match (partner, known) {
        (Some((x, fx)), Some((f0, _))) if fx * f0 < 0.0 && x.len() == d => {
            Some((x.iter().zip(&w).map(|(xi, wi)| xi - wi).collect(), fx))
        }
        _ => None,
    };
    loop {
        let gradient_fits = spent + budget.gradient_cost <= limit;
        let use_adjoint = adjoint && !stalled && (gradient_fits || !budget.restart);
        let (g, f0, l0, given) = if let Some((g, fx)) = segment.take() {
            let (f0, l0) = here.expect("a partner counts only with a known start");
            (g, f0, l0, Some(fx))
        } else if use_adjoint {
            // The first gradient runs whatever the budget; later ones only where they fit.
            if spent > 0.0 && !gradient_fits {
                return Ok(());
            }
            let p = probe(&w, true, &mut spent, &mut best)?;
            here = Some((p.indicator, p.loss));
            (p.grad.unwrap_or_default(), p.indicator, p.loss, None)
        } else {
            let (f0, l0) = match here {
                Some(v) => v,
                None => {
                    if spent + 1.0 > limit {
                        return Ok(());
                    }
                    let p = probe(&w, false, &mut spent, &mut best)?;
                    here = Some((p.indicator, p.loss));
                    (p.indicator, p.loss)
                }
            };
            let g = (0..d).map(|_| rng.normal()).collect::<Vec<f64>>();
            (g, f0, l0, None)
        };
        stalled = false;
        let norm = g.iter().map(|x| x * x).sum::<f64>().sqrt();
        // The axis's unit in the parameters' units: an axis is normalised (steps of
        // LINE_STEPS are distances), the segment is not (its bracket [0, 1] spans it).
        let (n, scale) = if given.is_some() {
            (1.0, norm)
        } else {
            (norm, 1.0)
        };
        if given.is_none() && (!(n > 0.0 && n.is_finite()) || (f0 == 0.0 && !budget.restart)) {
            if budget.restart && spent + 1.0 <= limit {
                // No direction from the adjoint here: a random axis next.
                stalled = true;
                continue;
            }
            return Ok(());
        }
        let at = |a: f64| -> Vec<f64> {
            w.iter()
                .zip(&g)
                .map(|(wi, gi)| (wi + a * gi / n).clamp(-1.0, 1.0))
                .collect()
        };
        // Bracket: the segment's far end, or a step whose indicator has the other sign than
        // at w.
        let mut lower: Option<(f64, Vec<f64>, f64)> = None;
        let bracket = match given {
            Some(fx) => Some((1.0, fx)),
            None => {
                let mut bracket = None;
                'steps: for a in LINE_STEPS {
                    for a in [a, -a] {
                        if spent + 1.0 > limit {
                            return Ok(());
                        }
                        let x = at(a);
                        let p = probe(&x, false, &mut spent, &mut best)?;
                        let (f, l) = (p.indicator, p.loss);
                        if l < l0 && lower.as_ref().is_none_or(|b| l < b.0) {
                            lower = Some((l, x, f));
                        }
                        if f * f0 <= 0.0 {
                            bracket = Some((a, f));
                            break 'steps;
                        }
                    }
                }
                bracket
            }
        };
        let Some((b, fb)) = bracket else {
            match lower {
                Some((l, x, f)) => {
                    w = x;
                    here = Some((f, l));
                    continue;
                }
                // The gradient at the same w would be the same.
                None if adjoint && !budget.restart => return Ok(()),
                None => {
                    stalled = adjoint;
                    continue;
                }
            }
        };
        // Illinois regula falsi on [0, b] (or [b, 0]).
        let mut ends = Illinois {
            a: 0.0,
            fa: f0,
            b,
            fb,
        };
        while spent + 1.0 <= limit && ends.fb != 0.0 && (ends.b - ends.a).abs() * scale > closed {
            let x = ends.next();
            let p = probe(&at(x), false, &mut spent, &mut best)?;
            ends.update(x, p.indicator);
        }
        if !budget.restart || spent + 1.0 > limit {
            return Ok(());
        }
        // Closed early: again from the lowest-loss point so far.
        let (l, x, f) = best.clone().expect("a bracket ran rollouts");
        w = x;
        here = Some((f, l));
    }
}

/// A bracket `[a, b]` of a root of `f` (`f(a)·f(b) ≤ 0`) for the Illinois variant of regula
/// falsi: `b` is always the newest point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Illinois {
    pub a: f64,
    pub fa: f64,
    pub b: f64,
    pub fb: f64,
}

impl Illinois {
    /// The secant's root, or the midpoint where the secant leaves the bracket.
    pub fn next(&self) -> f64 {
        let x = (self.a * self.fb - self.b * self.fa) / (self.fb - self.fa);
        if x.is_finite() && (x - self.a) * (x - self.b) < 0.0 {
            x
        } else {
            0.5 * (self.a + self.b)
        }
    }

    /// Takes `f(x) = fx`. The newest point replaces `b`; `a` is kept where the signs say so,
    /// and each time it is kept its value is halved, so that a steep curve cannot pin the
    /// secant to one end (plain regula falsi's stall).
    pub fn update(&mut self, x: f64, fx: f64) {
        if fx * self.fb > 0.0 {
            self.fa *= 0.5;
        } else {
            (self.a, self.fa) = (self.b, self.fb);
        }
        (self.b, self.fb) = (x, fx);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Solves `f = 0` from the bracket `[0, b]` in `n` evaluations; the last `f`.
    fn solve(f: impl Fn(f64) -> f64, b: f64, n: usize) -> f64 {
        let mut e = Illinois {
            a: 0.0,
            fa: f(0.0),
            b,
            fb: f(b),
        };
        for _ in 0..n {
            let x = e.next();
            e.update(x, f(x));
        }
        e.fb
    }

    /// A dose cliff: 4.5 g over the cup at 0, nothing past 0.4, a steep ramp at 0.27, and the
    /// target 2 g; the signed indicator is target − delivered. One grain weighs 0.023 g.
    fn cliff(x: f64) -> f64 {
        2.0 - 4.5 / (1.0 + ((x - 0.27) / 0.01).exp())
    }

    #[test]
    fn illinois_finds_the_dose_on_a_steep_cliff() {
        let f = solve(cliff, 0.4, 12);
        assert!(f.abs() < 0.012, "half a grain: {f}");
        // The same from the other side of the bracket.
        assert!(solve(|x| cliff(0.4 - x), 0.4, 12).abs() < 0.012);
    }

    #[test]
    fn illinois_stays_in_the_bracket_on_a_staircase() {
        // Whole grains: the dose moves in steps of 0.023 g, so only a point within one step of
        // the target exists; the bracket must still close on it.
        let step = |x: f64| {
            let delivered = 4.5 / (1.0 + ((x - 0.27) / 0.01).exp());
            2.0 - (delivered / 0.023).floor() * 0.023
        };
        let mut e = Illinois {
            a: 0.0,
            fa: step(0.0),
            b: 0.4,
            fb: step(0.4),
        };
        for _ in 0..30 {
            let x = e.next();
            assert!((0.0..=0.4).contains(&x), "{x} left the bracket");
            e.update(x, step(x));
            assert!(e.fa * e.fb <= 0.0, "lost the bracket: {e:?}");
        }
        assert!(e.fb.abs() <= 0.023, "{e:?}");
    }

    /// A dose in five parameters: a steep cliff across `v·w = 0.27`, in whole grains of 0.023 g,
    /// and a soft mass whose gradient points across the cliff (but with the wrong sign past
    /// it, as the cup's soft count's can). Target 2 g; the loss is the dosing loss.
    fn dose(w: &[f64], grad: bool) -> Probe {
        let v = [0.6, -0.3, 0.5, 0.4, 0.37];
        let s: f64 = w.iter().zip(v).map(|(a, b)| a * b).sum();
        let soft = 4.5 / (1.0 + ((s - 0.27) / 0.01).exp());
        let delivered = (soft / 0.023).floor() * 0.023;
        let f = 2.0 - delivered;
        let dsoft = -soft * (1.0 - soft / 4.5) / 0.01;
        Probe {
            indicator: f,
            loss: (f / 2.0).powi(2),
            grad: grad.then(|| {
                v.iter()
                    .map(|vi| -(2.0 - soft) / 2.0 * dsoft * vi)
                    .collect()
            }),
        }
    }

    fn run(adjoint: bool, restart: bool, start: [f64; 5]) -> (Vec<(bool, Probe)>, f64) {
        run_from(adjoint, restart, CLOSED, start, None)
    }

    /// [`run`] with a bracket width and a partner (its point; the start's and its indicators are
    /// the `dose`'s, as a caller that ran both would know them).
    fn run_from(
        adjoint: bool,
        restart: bool,
        closed: f64,
        start: [f64; 5],
        partner: Option<[f64; 5]>,
    ) -> (Vec<(bool, Probe)>, f64) {
        let mut seen = Vec::new();
        let budget = Budget {
            forward_rollouts: 20.0,
            gradient_cost: 3.4,
            restart,
            closed,
        };
        let known = partner.map(|_| {
            let p = dose(&start, false);
            (p.indicator, p.loss)
        });
        let partner = partner.map(|x| (x, dose(&x, false).indicator));
        search(
            &start,
            known,
            partner.as_ref().map(|(x, f)| (&x[..], *f)),
            budget,
            adjoint,
            &mut SplitMix64(7),
            &mut |w, g| {
                assert!(
                    w.iter().all(|x| (-1.0..=1.0).contains(x)),
                    "left the box: {w:?}"
                );
                let p = dose(w, g);
                seen.push((g, p.clone()));
                Ok(p)
            },
        )
        .unwrap();
        let spent = seen.iter().map(|(g, _)| if *g { 3.4 } else { 1.0 }).sum();
        (seen, spent)
    }

    #[test]
    fn the_adjoint_line_finds_the_dose_within_a_grain_and_its_budget() {
        // Start over-delivering (4.5 g): the dose lies across the cliff.
        let (seen, spent) = run(true, false, [0.0; 5]);
        assert!(seen[0].0, "the first rollout is the gradient's");
        assert!(spent <= 20.0 + 1e-9, "{spent}");
        let best = seen
            .iter()
            .map(|(_, p)| p.indicator.abs())
            .fold(f64::MAX, f64::min);
        assert!(best <= 0.023, "one grain: {best}");
    }

    #[test]
    fn a_partner_across_the_target_is_searched_first_and_closes_at_the_width_asked() {
        // The start over-delivers (4.5 g), the partner delivers nothing: the segment brackets.
        let (start, far) = ([0.0; 5], [0.5; 5]);
        let (seen, _) = run_from(true, false, CLOSED, start, Some(far));
        assert!(
            seen.iter().all(|(g, _)| !g),
            "no gradient on a known bracket"
        );
        let best = seen
            .iter()
            .map(|(_, p)| p.indicator.abs())
            .fold(f64::MAX, f64::min);
        assert!(best <= 0.023, "one grain: {best}");
        // With a coarse width the bracket closes early and, with restarts, the adjoint's axis
        // takes the rest of the budget from the lowest-loss point.
        let (seen, spent) = run_from(true, true, 0.05, start, Some(far));
        let first_gradient = seen.iter().position(|(g, _)| *g).expect("a restart");
        assert!(first_gradient > 0, "the segment comes first");
        assert!(spent <= 20.0 + 1e-9 && spent > 19.0, "{spent}");
        // A partner on the same side is no bracket: the adjoint's axis comes first.
        let (seen, _) = run_from(true, false, CLOSED, start, Some([-0.1; 5]));
        assert!(seen[0].0, "{:?}", seen[0]);
    }

    #[test]
    fn with_restarts_the_whole_budget_is_spent_and_never_exceeded() {
        for adjoint in [true, false] {
            let (_, spent) = run(adjoint, true, [0.0; 5]);
            assert!(spent <= 20.0 + 1e-9 && spent > 19.0, "{adjoint}: {spent}");
        }
        // A start where nothing moves (the whole load far inside the cup, zero gradient):
        // without restarts the adjoint stops after its gradient rollout, with them random axes
        // spend the rest.
        let flat = [-1.0; 5];
        assert_eq!(run(true, false, flat).0.len(), 1);
        let (seen, spent) = run(true, true, flat);
        assert!(spent > 19.0, "{spent}");
        assert!(
            seen[1..].iter().all(|(g, _)| !g),
            "no second gradient at the same point"
        );
    }
}
