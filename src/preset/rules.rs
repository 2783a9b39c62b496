//! The walk over the whole preset and the rules that span sections: periods that must divide,
//! names that must be unique and exist, and steps that an explicit integrator or a filter
//! must be able to take.

use std::collections::BTreeMap;

use super::fields::{Fields, Num, Walker, short};
use super::{
    AccDec, AccDecKind, AxisParams, Coupling, Crossbeam, DiagnoseSettings, FieldError, Mode,
    NcParams, PlcEvent, PosSource, Preset, Scenario, Timing, ToolPost, ratio,
};
use crate::units;

/// Most axes a machine may have.
pub const MAX_AXES: usize = 8;
/// Most NC channels (programs) a machine may have.
pub const MAX_CHANNELS: usize = 8;
/// Most samples one acc/dec moving-average stage may hold: its time constant over its
/// period. 10⁶ samples are 8 MB per axis and stage.
pub const MAX_FILTER_SAMPLES: f64 = 1e6;
/// Most plant sub-steps per T3 a two-mass coupling may need.
pub const MAX_SUBSTEPS: u32 = 64;
/// Longest scenario, s (a little over 11 days of machine time).
pub const MAX_DURATION_S: f64 = 1e6;

crate::choice_enum!(Mode { Normal => "normal", Direct => "direct" });
crate::choice_enum!(AccDecKind { None => "none", Linear => "linear", Bell => "bell" });
crate::choice_enum!(PosSource { Load => "load", MotorEncoder => "motor_encoder", Scale => "scale" });

fn err(out: &mut Vec<FieldError>, path: impl Into<String>, reason: String) {
    out.push(FieldError {
        path: path.into(),
        reason,
    });
}

/// A period T1, T2 or T3: 1 µs to 1 s.
const PERIOD_S: Num = Num::closed("s", 1e-6, 1.0);
/// A feed: up to 1000 m/min.
const FEED_MM_PER_MIN: Num = Num::above("mm/min", 0.0, 1e6);

impl Fields for Timing {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.num("t1_s", "T1", &mut self.t1_s, PERIOD_S);
        w.num("t2_s", "T2", &mut self.t2_s, PERIOD_S);
        w.num("t3_s", "T3", &mut self.t3_s, PERIOD_S);
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        let ok = |x: f64| PERIOD_S.accepts(x);
        if !(ok(self.t1_s) && ok(self.t2_s) && ok(self.t3_s)) {
            return;
        }
        if ratio(self.t1_s, self.t2_s).is_none() {
            err(
                out,
                format!("{at}.t1_s"),
                format!(
                    "T1 = {} s is not an integer multiple (≥ 1) of T2 = {} s",
                    short(self.t1_s),
                    short(self.t2_s)
                ),
            );
        }
        if ratio(self.t2_s, self.t3_s).is_none() {
            err(
                out,
                format!("{at}.t2_s"),
                format!(
                    "T2 = {} s is not an integer multiple (≥ 1) of T3 = {} s",
                    short(self.t2_s),
                    short(self.t3_s)
                ),
            );
        }
    }
}

impl Fields for AccDec {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.choice("kind", "acc/dec", &mut self.kind);
        let kind = self.kind;
        w.when(kind != AccDecKind::None, |w| {
            w.num(
                "tc1_s",
                "time constant 1",
                &mut self.tc1_s,
                Num::closed("s", 0.0, 10.0),
            );
        });
        w.when(kind == AccDecKind::Bell, |w| {
            w.num(
                "tc2_s",
                "time constant 2",
                &mut self.tc2_s,
                Num::closed("s", 0.0, 10.0),
            );
        });
    }
}

impl Fields for NcParams {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.choice("initial_mode", "initial mode", &mut self.initial_mode);
        w.nest("accdec", |w| self.accdec.fields(w));
        w.num(
            "rapid_mm_per_min",
            "rapid feed",
            &mut self.rapid_mm_per_min,
            FEED_MM_PER_MIN,
        );
        w.num(
            "default_feed_mm_per_min",
            "default feed",
            &mut self.default_feed_mm_per_min,
            FEED_MM_PER_MIN,
        );
    }
}

impl Fields for ToolPost {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.text("x_axis", "beam axis", &mut self.x_axis);
        w.text("z_axis", "ram axis", &mut self.z_axis);
        w.num(
            "weight_n",
            "weight",
            &mut self.weight_n,
            Num::closed("N", 0.0, 1e7),
        );
    }
}

impl Fields for Crossbeam {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.flag("enabled", "crossbeam on", &mut self.enabled);
        w.when(self.enabled, |w| {
            w.num(
                "span_mm",
                "span",
                &mut self.span_mm,
                Num::above("mm", 0.0, 1e5),
            );
            w.num(
                "youngs_modulus_gpa",
                "Young's modulus",
                &mut self.youngs_modulus_gpa,
                Num::above("GPa", 0.0, 1e4),
            );
            w.num(
                "area_moment_cm4",
                "second moment of area",
                &mut self.area_moment_cm4,
                Num::above("cm^4", 0.0, 1e9),
            );
            w.num(
                "self_weight_n_per_m",
                "self-weight",
                &mut self.self_weight_n_per_m,
                Num::closed("N/m", 0.0, 1e7),
            );
            for (i, p) in self.posts.iter_mut().enumerate() {
                w.nest(&format!("posts.{i}"), |w| p.fields(w));
            }
        });
    }
}

impl Fields for PlcEvent {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.num(
            "t_s",
            "at",
            &mut self.t_s,
            Num::closed("s", 0.0, MAX_DURATION_S),
        );
        w.choice("mode", "mode", &mut self.mode);
        w.index(
            "channel",
            "channel",
            &mut self.channel,
            0,
            MAX_CHANNELS as u64 - 1,
        );
    }
}

impl Fields for Scenario {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.ron("programs", "programs", &mut self.programs);
        for (i, p) in self.programs.iter_mut().enumerate() {
            w.text(&format!("programs.{i}"), "program", p);
        }
        w.opt_num(
            "duration_s",
            "duration",
            &mut self.duration_s,
            Num::above("s", 0.0, MAX_DURATION_S),
        );
        w.num(
            "settle_s",
            "settle time",
            &mut self.settle_s,
            Num::closed("s", 0.0, 1e4),
        );
        w.count(
            "trace_every",
            "trace every",
            &mut self.trace_every,
            1,
            1_000_000_000,
        );
        w.ron("plc_events", "PLC events", &mut self.plc_events);
        for (i, e) in self.plc_events.iter_mut().enumerate() {
            w.nest(&format!("plc_events.{i}"), |w| e.fields(w));
        }
    }

    fn rules(&self, at: &str, out: &mut Vec<FieldError>) {
        if self.programs.is_empty() || self.programs.len() > MAX_CHANNELS {
            err(
                out,
                format!("{at}.programs"),
                format!(
                    "needs 1 to {MAX_CHANNELS} programs (one per channel), has {}",
                    self.programs.len()
                ),
            );
        }
        for (i, w) in self.plc_events.windows(2).enumerate() {
            if w[1].t_s < w[0].t_s {
                err(
                    out,
                    format!("{at}.plc_events.{}.t_s", i + 1),
                    "events must be in time order".into(),
                );
            }
        }
        for (i, e) in self.plc_events.iter().enumerate() {
            if e.channel >= self.programs.len() {
                err(
                    out,
                    format!("{at}.plc_events.{i}.channel"),
                    format!("no channel {}", e.channel),
                );
            }
        }
    }
}

impl Fields for DiagnoseSettings {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.opt_text("mapping", "record column mapping", &mut self.mapping);
        w.choice("pos_source", "record position from", &mut self.pos_source);
    }
}

impl Fields for Preset {
    fn fields(&mut self, w: &mut Walker<'_>) {
        w.text("name", "name", &mut self.name);
        w.text("description", "description", &mut self.description);
        w.nest("timing", |w| self.timing.fields(w));
        w.nest("nc", |w| self.nc.fields(w));
        for a in &mut self.axes {
            let name = a.name.clone();
            w.nest(&format!("axes.{name}"), |w| a.fields(w));
        }
        w.nest("crossbeam", |w| self.crossbeam.fields(w));
        w.ron("cross", "cross tables", &mut self.cross);
        for (i, t) in self.cross.iter_mut().enumerate() {
            w.nest(&format!("cross.{i}"), |w| t.fields(w));
        }
        w.nest("scenario", |w| self.scenario.fields(w));
        w.nest("diagnose", |w| self.diagnose.fields(w));
    }

    fn rules(&self, _at: &str, out: &mut Vec<FieldError>) {
        self.timing.rules("timing", out);
        self.scenario.rules("scenario", out);
        self.axes_rules(out);
        self.step_rules(out);
        self.cross_rules(out);
        self.crossbeam_rules(out);
    }
}

impl Preset {
    fn axes_rules(&self, out: &mut Vec<FieldError>) {
        if self.axes.is_empty() || self.axes.len() > MAX_AXES {
            err(
                out,
                "axes",
                format!(
                    "a machine needs 1 to {MAX_AXES} axes, has {}",
                    self.axes.len()
                ),
            );
        }
        let mut names = BTreeMap::new();
        let mut letters = BTreeMap::new();
        for (i, a) in self.axes.iter().enumerate() {
            let at = format!("axes.{}", a.name);
            a.rules(&at, out);
            if names.insert(a.name.clone(), i).is_some() {
                err(out, format!("{at}.name"), "duplicate axis name".into());
            }
            if letters.insert((a.channel, a.letter), i).is_some() {
                err(
                    out,
                    format!("{at}.letter"),
                    format!("letter {} is used twice in channel {}", a.letter, a.channel),
                );
            }
            if a.channel >= self.scenario.programs.len() {
                err(
                    out,
                    format!("{at}.channel"),
                    format!(
                        "channel {} has no program (scenario.programs has {})",
                        a.channel,
                        self.scenario.programs.len()
                    ),
                );
            }
        }
    }

    /// Steps the model takes with the preset's periods: explicit integrators must be
    /// stable, filters and sub-steps bounded.
    fn step_rules(&self, out: &mut Vec<FieldError>) {
        let t = &self.timing;
        if !(PERIOD_S.accepts(t.t1_s) && PERIOD_S.accepts(t.t3_s)) {
            return;
        }
        let ad = &self.nc.accdec;
        let shortest = t.t3_s;
        for (name, tc) in [("tc1_s", ad.tc1_s), ("tc2_s", ad.tc2_s)] {
            let n = tc / shortest;
            if n.is_finite() && n > MAX_FILTER_SAMPLES {
                err(
                    out,
                    format!("nc.accdec.{name}"),
                    format!(
                        "{} s is {n:.3e} moving-average samples at T3 = {shortest} s (direct mode); \
                         at most {MAX_FILTER_SAMPLES:e} (shorten it or lengthen T3)",
                        short(tc)
                    ),
                );
            }
        }
        for a in &self.axes {
            axis_step_rules(a, t.t3_s, t.t2_s, out);
        }
    }

    fn cross_rules(&self, out: &mut Vec<FieldError>) {
        for (i, t) in self.cross.iter().enumerate() {
            t.rules(&format!("cross.{i}"), out);
            for (field, name) in [("base_axis", &t.base_axis), ("comp_axis", &t.comp_axis)] {
                if !self.axes.iter().any(|a| &a.name == name) {
                    err(
                        out,
                        format!("cross.{i}.{field}"),
                        format!("no axis named '{name}'"),
                    );
                }
            }
        }
    }

    fn crossbeam_rules(&self, out: &mut Vec<FieldError>) {
        let cb = &self.crossbeam;
        if !cb.enabled {
            return;
        }
        if cb.posts.is_empty() || cb.posts.len() > 2 {
            err(
                out,
                "crossbeam.posts",
                format!("needs one or two tool posts, found {}", cb.posts.len()),
            );
        }
        for (i, post) in cb.posts.iter().enumerate() {
            for (field, name) in [("x_axis", &post.x_axis), ("z_axis", &post.z_axis)] {
                if !self.axes.iter().any(|a| &a.name == name) {
                    err(
                        out,
                        format!("crossbeam.posts.{i}.{field}"),
                        format!("no axis named '{name}'"),
                    );
                }
            }
        }
    }
}

/// The explicit steps of one axis: the screw-temperature Euler step and the thermal
/// predictor must not overshoot (step × loss / capacity ≤ 1), and a two-mass coupling must
/// be resolved within [`MAX_SUBSTEPS`] sub-steps per T3.
fn axis_step_rules(a: &AxisParams, t3_s: f64, t2_s: f64, out: &mut Vec<FieldError>) {
    let at = format!("axes.{}", a.name);
    let th = &a.screw_thermal;
    if th.enabled && th.heat_capacity_j_per_k > 0.0 {
        let r = t3_s * th.loss_w_per_k / th.heat_capacity_j_per_k;
        if r > 1.0 {
            err(
                out,
                format!("{at}.screw_thermal.heat_capacity_j_per_k"),
                format!(
                    "{} J/K with a loss of {} W/K gives a thermal time constant of {:.3e} s, \
                     shorter than T3 = {t3_s} s: the temperature step would overshoot \
                     (need capacity ≥ loss × T3 = {:.3e} J/K)",
                    short(th.heat_capacity_j_per_k),
                    short(th.loss_w_per_k),
                    th.heat_capacity_j_per_k / th.loss_w_per_k,
                    th.loss_w_per_k * t3_s
                ),
            );
        }
    }
    let tc = &a.thermal;
    if tc.enabled && tc.capacity_j_per_k > 0.0 && t2_s * tc.loss_w_per_k / tc.capacity_j_per_k > 1.0
    {
        err(
            out,
            format!("{at}.thermal.capacity_j_per_k"),
            format!(
                "the predictor's time constant {:.3e} s is shorter than its step T2 = {t2_s} s \
                 (need capacity ≥ loss × T2 = {:.3e} J/K)",
                tc.capacity_j_per_k / tc.loss_w_per_k,
                tc.loss_w_per_k * t2_s
            ),
        );
    }
    if tc.enabled && tc.source == super::comp::Source::Temperature && tc.sensor_lag_s < t2_s {
        err(
            out,
            format!("{at}.thermal.sensor_lag_s"),
            format!(
                "{} s is shorter than the step T2 = {t2_s} s",
                tc.sensor_lag_s
            ),
        );
    }
    if !matches!(a.drive.coupling, Coupling::Rigid) {
        let n = a.required_substeps(t3_s);
        if n.is_finite() && n > f64::from(MAX_SUBSTEPS) {
            err(
                out,
                format!("{at}.drive.coupling.stiffness_n_per_um"),
                format!(
                    "the coupling resonance needs {n:.0} plant sub-steps per T3 = {t3_s} s; \
                     at most {MAX_SUBSTEPS} (soften the coupling, add mass, or shorten T3)"
                ),
            );
        }
    }
}

impl AxisParams {
    /// Plant sub-steps per T3 that resolve the coupling: 0.3 rad of the resonance and half
    /// the damping time per sub-step (unbounded; validation caps it at [`MAX_SUBSTEPS`]).
    pub fn required_substeps(&self, t3_s: f64) -> f64 {
        match self.drive.coupling {
            Coupling::Rigid => 1.0,
            Coupling::TwoMass {
                stiffness_n_per_um,
                damping_n_s_per_m,
            } => resolving_substeps(
                self.drive.reflected_motor_mass_kg(),
                self.drive.table_mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
                t3_s,
            ),
            Coupling::Payload {
                mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
                hardening_deflection_um,
            } => {
                let near_kg = self.drive.reflected_motor_mass_kg() + self.drive.table_mass_kg;
                let k = stiffness_n_per_um
                    * self.payload_stiffening(mass_kg, stiffness_n_per_um, hardening_deflection_um);
                resolving_substeps(near_kg, mass_kg, k, damping_n_s_per_m, t3_s)
            }
        }
    }
}

impl AxisParams {
    /// The coupling's mode at rest: the reduced mass of the two masses it joins (kg), its
    /// stiffness (N/m) and its damping (N·s/m); None for a rigid drive.
    fn coupling_mode(&self) -> Option<(f64, f64, f64)> {
        let (m_a, m_b, k_n_per_um, c) = match self.drive.coupling {
            Coupling::Rigid => return None,
            Coupling::TwoMass {
                stiffness_n_per_um,
                damping_n_s_per_m,
            } => (
                self.drive.reflected_motor_mass_kg(),
                self.drive.table_mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
            ),
            Coupling::Payload {
                mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
                ..
            } => (
                self.drive.reflected_motor_mass_kg() + self.drive.table_mass_kg,
                mass_kg,
                stiffness_n_per_um,
                damping_n_s_per_m,
            ),
        };
        let m_red = m_a * m_b / (m_a + m_b);
        Some((m_red, units::n_per_um_to_n_per_m(k_n_per_um), c))
    }

    /// Damping ratio of the coupling's mode, c / (2·√(k·m)) over the reduced mass of the two
    /// masses it joins (at rest, for a hardening mount); None for a rigid drive.
    pub fn coupling_damping_ratio(&self) -> Option<f64> {
        self.coupling_mode()
            .map(|(m_red, k, c)| c / (2.0 * (k * m_red).sqrt()))
    }

    /// Undamped natural frequency of the coupling's mode, √(k/m) over the same reduced mass
    /// (rad/s, at rest); None for a rigid drive.
    pub fn coupling_resonance_rad_per_s(&self) -> Option<f64> {
        self.coupling_mode().map(|(m_red, k, _)| (k / m_red).sqrt())
    }

    /// How much stiffer than at rest a hardening payload mount ([`Coupling::Payload`]) can
    /// get: its tangent stiffness where it carries twice the force that accelerates the
    /// payload along with the whole axis at the motor's torque limit (the quasi-static
    /// share, doubled for the overshoot of a lightly damped mount). 1 for a linear mount.
    fn payload_stiffening(&self, mass_kg: f64, k_n_per_um: f64, d0_um: f64) -> f64 {
        if !(d0_um > 0.0 && k_n_per_um > 0.0) {
            return 1.0;
        }
        let f_max_n = self.servo.torque_limit_nm.abs() * self.drive.force_per_torque();
        let f_n = 2.0 * f_max_n * mass_kg / self.drive.total_mass_kg().max(1e-9);
        // k·d·(1 + (d/d0)²) = f: d/d0 = r solves r + r³ = f/(k·d0); r below both roots.
        let q = f_n / (k_n_per_um * d0_um);
        let r = q.min(q.cbrt());
        if r.is_finite() {
            1.0 + 3.0 * r * r
        } else {
            1.0
        }
    }
}

/// Sub-steps of T3 that resolve a spring `k` (N/µm) with damper `c` between masses `m_a` and
/// `m_b`: 0.3 rad of the resonance and half the damping time per sub-step.
fn resolving_substeps(m_a: f64, m_b: f64, k_n_per_um: f64, c_n_s_per_m: f64, t3_s: f64) -> f64 {
    let m_red = m_a * m_b / (m_a + m_b);
    let omega = (units::n_per_um_to_n_per_m(k_n_per_um) / m_red).sqrt();
    let by_k = (t3_s * omega / 0.3).ceil();
    let by_c = (t3_s * c_n_s_per_m / m_red / 0.5).ceil();
    by_k.max(by_c).max(1.0)
}
