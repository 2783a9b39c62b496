//! Unit conversions at the boundaries.
//!
//! Presets and traces use the units an engineer reads (mm, µm, ms, mm/min); the model works
//! in SI. Every conversion between the two goes through one of these named helpers, so a
//! reader sees *which* units meet and a wrong factor is a wrong name, not a stray `1e-3`.

// Conversions multiply by the exact integer factor going to the small unit and divide by it
// coming back, so that mm → m → mm returns the number written in the file far more often
// than multiplying by the inexact 1e-3 would.
/// Millimetres per metre.
const MM_PER_M: f64 = 1000.0;
/// Micrometres per metre.
const UM_PER_M: f64 = 1_000_000.0;
/// Micrometres per millimetre.
const UM_PER_MM: f64 = 1000.0;
/// Milliseconds per second.
const MS_PER_S: f64 = 1000.0;

/// mm → m.
#[inline]
pub fn mm_to_m(mm: f64) -> f64 {
    mm / MM_PER_M
}

/// m → mm.
#[inline]
pub fn m_to_mm(m: f64) -> f64 {
    m * MM_PER_M
}

/// µm → m.
#[inline]
pub fn um_to_m(um: f64) -> f64 {
    um / UM_PER_M
}

/// m → µm.
#[inline]
pub fn m_to_um(m: f64) -> f64 {
    m * UM_PER_M
}

/// µm → mm.
#[inline]
pub fn um_to_mm(um: f64) -> f64 {
    um / UM_PER_MM
}

/// mm → µm.
#[inline]
pub fn mm_to_um(mm: f64) -> f64 {
    mm * UM_PER_MM
}

/// ms → s.
#[inline]
pub fn ms_to_s(ms: f64) -> f64 {
    ms / MS_PER_S
}

/// s → ms.
#[inline]
pub fn s_to_ms(s: f64) -> f64 {
    s * MS_PER_S
}

/// mm/s → m/s.
#[inline]
pub fn mm_per_s_to_m_per_s(v: f64) -> f64 {
    mm_to_m(v)
}

/// m/s → mm/s.
#[inline]
pub fn m_per_s_to_mm_per_s(v: f64) -> f64 {
    m_to_mm(v)
}

/// mm/min → m/s.
#[inline]
pub fn mm_per_min_to_m_per_s(v: f64) -> f64 {
    mm_to_m(v) / 60.0
}

/// mm/min → mm/s (trace velocities are held in mm/s).
#[inline]
pub fn mm_per_min_to_mm_per_s(v: f64) -> f64 {
    v / 60.0
}

/// mm/s → mm/min.
#[inline]
pub fn mm_per_s_to_mm_per_min(v: f64) -> f64 {
    v * 60.0
}

/// m/s → mm/min.
#[inline]
pub fn m_per_s_to_mm_per_min(v: f64) -> f64 {
    m_to_mm(v) * 60.0
}

/// mm/s² → m/s² (an acceleration).
#[inline]
pub fn mm_per_s2_to_m_per_s2(a: f64) -> f64 {
    mm_to_m(a)
}

/// Position-loop gain Kp (1/s) → the servo gain factor Kv in (m/min)/mm that SINUMERIK
/// (MD32200) uses: the feed in m/min that gives 1 mm of following error.
#[inline]
pub fn kp_per_s_to_kv_m_per_min_per_mm(kp: f64) -> f64 {
    kp * 60.0 / MM_PER_M
}

/// N/µm → N/m (a stiffness).
#[inline]
pub fn n_per_um_to_n_per_m(k: f64) -> f64 {
    k * UM_PER_M
}

/// N/m → N/µm (a stiffness).
#[inline]
pub fn n_per_m_to_n_per_um(k: f64) -> f64 {
    k / UM_PER_M
}

/// GPa → Pa.
#[inline]
pub fn gpa_to_pa(e: f64) -> f64 {
    e * 1e9
}

/// cm⁴ → m⁴ (a second moment of area).
#[inline]
pub fn cm4_to_m4(i: f64) -> f64 {
    i * 1e-8
}

/// µm/m → m/m (a relative length error).
#[inline]
pub fn um_per_m_to_ratio(x: f64) -> f64 {
    x / UM_PER_M
}

/// m/m → µm/m (a relative length error).
#[inline]
pub fn ratio_to_um_per_m(x: f64) -> f64 {
    x * UM_PER_M
}

/// Load-side force per motor torque for a screw of lead `lead_m`: F = 2π/lead · τ.
#[inline]
pub fn force_per_torque(lead_m: f64) -> f64 {
    std::f64::consts::TAU / lead_m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_invert_each_other() {
        for x in [0.0, 1.0, -2.5, 1234.5678, 1e-9] {
            assert!((m_to_mm(mm_to_m(x)) - x).abs() <= 1e-12 * x.abs().max(1.0));
            assert!((m_to_um(um_to_m(x)) - x).abs() <= 1e-12 * x.abs().max(1.0));
            assert!((mm_to_um(um_to_mm(x)) - x).abs() <= 1e-12 * x.abs().max(1.0));
            assert!((s_to_ms(ms_to_s(x)) - x).abs() <= 1e-12 * x.abs().max(1.0));
            let v = mm_per_min_to_m_per_s(x);
            assert!((m_per_s_to_mm_per_min(v) - x).abs() <= 1e-12 * x.abs().max(1.0));
            let w = mm_per_min_to_mm_per_s(x);
            assert!((mm_per_s_to_mm_per_min(w) - x).abs() <= 1e-12 * x.abs().max(1.0));
        }
        assert_eq!(mm_to_m(1000.0), 1.0);
        assert_eq!(um_to_mm(1000.0), 1.0);
        assert_eq!(mm_per_min_to_m_per_s(60_000.0), 1.0);
        assert_eq!(mm_per_min_to_mm_per_s(60.0), 1.0);
        assert_eq!(n_per_um_to_n_per_m(1.0), 1e6);
        assert!((force_per_torque(0.01) - 628.318_530_717_958_6).abs() < 1e-9);
    }
}

/// The symbol a unit is shown with: the file spellings of TRACE_FORMAT and presets (`um`,
/// `N*m`, `N*s/m`, `degC`) as SI writes them (µm, N·m, N·s/m, °C). Everything a user reads
/// goes through here, so one unit never appears in two spellings.
pub fn symbol(unit: &str) -> String {
    match unit {
        "um" => "µm".to_owned(),
        "degC" => "°C".to_owned(),
        "um/s" => "µm/s".to_owned(),
        u => u.replace('*', "·"),
    }
}

/// Significant digits a value is shown with.
const SIG_DIGITS: i32 = 4;

/// A number at a precision that fits its size: [`SIG_DIGITS`] significant digits, plain
/// notation from 1e-4 to 1e7, no trailing zeros after the point (160.6, 0.6021, 20.07),
/// an exponent outside; "—" for a value that is not finite.
pub fn fmt_num(v: f64) -> String {
    fmt_sig(v, SIG_DIGITS)
}

/// [`fmt_num`] with `digits` significant digits (an editable field shows more).
pub fn fmt_sig(v: f64, digits: i32) -> String {
    if !v.is_finite() {
        return "—".to_owned();
    }
    if v == 0.0 {
        return "0".to_owned();
    }
    let digits = digits.clamp(1, 17);
    // Round first, so 9.9996 at four digits becomes 10 and is placed as 10.
    let rounded: f64 = format!("{v:.*e}", (digits - 1) as usize)
        .parse()
        .unwrap_or(v);
    let mag = rounded.abs().log10().floor() as i32;
    if !(-4..7).contains(&mag) {
        return format!("{rounded:.*e}", (digits - 1) as usize);
    }
    let decimals = (digits - 1 - mag).max(0) as usize;
    let s = format!("{rounded:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        s
    }
}

/// A value with its unit symbol, e.g. `fmt_qty(20.07, "N")` → "20.07 N".
pub fn fmt_qty(v: f64, unit: &str) -> String {
    let sym = symbol(unit);
    if sym.is_empty() {
        fmt_num(v)
    } else {
        format!("{} {sym}", fmt_num(v))
    }
}

#[cfg(test)]
mod fmt_tests {
    use super::*;

    #[test]
    fn numbers_show_four_significant_digits_and_si_symbols() {
        assert_eq!(fmt_num(160.6170160), "160.6");
        assert_eq!(fmt_num(20.07), "20.07");
        assert_eq!(fmt_num(0.602134), "0.6021");
        assert_eq!(fmt_num(8227.0), "8227");
        assert_eq!(fmt_num(-1.5e-6), "-1.500e-6");
        assert_eq!(fmt_num(f64::NAN), "—");
        assert_eq!(fmt_qty(9.5, "um"), "9.5 µm");
        assert_eq!(fmt_qty(0.14, "N*m"), "0.14 N·m");
        assert_eq!(fmt_qty(300.0, "N*s/m"), "300 N·s/m");
        assert_eq!(fmt_qty(3.0, ""), "3");
        assert_eq!(fmt_num(9.99996), "10");
        assert_eq!(fmt_sig(160.6170160, 6), "160.617");
    }
}
