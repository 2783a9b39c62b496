//! Exact decimal shifts: a number's text multiplied by a power of ten by moving its decimal
//! point, never by float arithmetic.
//!
//! The writer takes the shortest round-trip text of an SI value (ryu) and moves its point to
//! the display unit (m → mm: three places right). The reader moves it back and parses with
//! `f64::from_str`, which rounds correctly; the text it parses is then exactly the decimal
//! ryu produced, which reads back as the original value. So `v` written in mm and read back
//! is `v`, bit for bit, where `m_to_mm` then `mm_to_m` may be an ulp off.

/// Plain decimal (no exponent) when the leading digit's power of ten lies in this range,
/// scientific notation outside: `0.000000001` and `123456789012345` are read more easily than
/// with an exponent, `1e-20` and `1e300` are shorter with one.
const PLAIN_EXP: std::ops::RangeInclusive<i32> = -9..=15;
/// Room for the significant digits of ryu's text (at most 17).
const MAX_DIGITS: usize = 24;
/// Longest text [`shift_ryu`] makes: a sign, `0.`, 8 zeros and 17 digits (28), or 17 digits
/// and 16 zeros (34), or a sign, `d.`, 16 digits, `e-` and 10 exponent digits (32).
const MAX_TEXT: usize = 40;

/// Appends to `out` the text of the finite value `v` times 10^`shift`, exactly: ryu's
/// shortest round-trip digits with the decimal point moved. `shift` 0 appends ryu's text as
/// it is.
pub(crate) fn push_shifted(out: &mut String, ryu: &mut ryu::Buffer, v: f64, shift: i32) {
    let text = ryu.format_finite(v);
    if shift == 0 {
        out.push_str(text);
        return;
    }
    let mut buf = [0u8; MAX_TEXT];
    let shifted = shift_ryu(text.as_bytes(), shift, &mut buf)
        .and_then(|n| std::str::from_utf8(buf.get(..n)?).ok());
    match shifted {
        Some(t) => out.push_str(t),
        // Not reached (ryu's grammar is the one parsed, its length bounded); the numeric
        // conversion is still the right number, within an ulp.
        None => out.push_str(ryu.format_finite(v * 10f64.powi(shift))),
    }
}

/// Writes ryu's text `-?d+(.d+)?(e-?d+)?` times 10^`shift` into `out`: plain within
/// [`PLAIN_EXP`], else `d.ddde±x`. Returns its length; None for text not of that form (ryu's
/// never is). One pass to read the digits, one to write them, on the stack: the writer calls
/// it for every cell.
fn shift_ryu(text: &[u8], shift: i32, out: &mut [u8; MAX_TEXT]) -> Option<usize> {
    let (neg, body) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    };
    // Significant digits (leading zeros dropped), digits after the point, the exponent.
    let mut digits = [0u8; MAX_DIGITS];
    let (mut n, mut frac, mut exp) = (0usize, 0i32, 0i32);
    let mut in_frac = false;
    for (i, &c) in body.iter().enumerate() {
        match c {
            b'.' => in_frac = true,
            b'e' => {
                exp = parse_exp(body.get(i + 1..)?)?;
                break;
            }
            b'0'..=b'9' => {
                frac += i32::from(in_frac);
                if n > 0 || c != b'0' {
                    *digits.get_mut(n)? = c;
                    n += 1;
                }
            }
            _ => return None,
        }
    }
    let mut end = n;
    while end > 0 && digits[end - 1] == b'0' {
        end -= 1;
    }
    let digits = &digits[..end];
    let exp = exp - frac + i32::try_from(n - end).ok()?;
    let mut w = Writer { out, at: 0 };
    if neg {
        w.byte(b'-')?;
    }
    let Some((&first, rest)) = digits.split_first() else {
        w.byte(b'0')?;
        return Some(w.at);
    };
    // Digits before the decimal point, and the power of ten of the leading digit.
    let len = i32::try_from(digits.len()).ok()?;
    let point = len + exp + shift;
    let lead = point - 1;
    if PLAIN_EXP.contains(&lead) {
        if point <= 0 {
            w.bytes(b"0.")?;
            w.zeros(-point)?;
            w.bytes(digits)?;
        } else if point >= len {
            w.bytes(digits)?;
            w.zeros(point - len)?;
        } else {
            let (int, fr) = digits.split_at(usize::try_from(point).ok()?);
            w.bytes(int)?;
            w.byte(b'.')?;
            w.bytes(fr)?;
        }
    } else {
        w.byte(first)?;
        if !rest.is_empty() {
            w.byte(b'.')?;
            w.bytes(rest)?;
        }
        w.byte(b'e')?;
        let mut buf = [0u8; 11];
        w.bytes(int_text(lead, &mut buf))?;
    }
    Some(w.at)
}

/// Appends bytes to a fixed buffer; None past its end.
struct Writer<'a> {
    out: &'a mut [u8; MAX_TEXT],
    at: usize,
}

impl Writer<'_> {
    fn byte(&mut self, c: u8) -> Option<()> {
        *self.out.get_mut(self.at)? = c;
        self.at += 1;
        Some(())
    }

    fn bytes(&mut self, s: &[u8]) -> Option<()> {
        s.iter().try_for_each(|&c| self.byte(c))
    }

    fn zeros(&mut self, k: i32) -> Option<()> {
        (0..k).try_for_each(|_| self.byte(b'0'))
    }
}

/// `text` times 10^`shift`, for `f64::from_str` to round once: its exponent (after the first
/// `e`/`E`, 0 without one) moved by `shift`, rewritten into `buf`. The result parses exactly
/// when `text` is a decimal number `[+-]digits[.digits][e[+-]digits]`; for anything else
/// (inf, NaN, other text) it does not parse either, and the caller parses `text` itself for
/// the right message. None when the exponent is not an integer of at most 9 digits or
/// overflows. No validation pass and no allocation once `buf` has grown: the reader calls it
/// for every cell.
pub(crate) fn shift_text<'a>(text: &str, shift: i32, buf: &'a mut String) -> Option<&'a str> {
    let bytes = text.as_bytes();
    let e_at = bytes
        .iter()
        .position(|&c| c == b'e' || c == b'E')
        .unwrap_or(bytes.len());
    let exp = match bytes.get(e_at + 1..) {
        Some(e) => parse_exp(e)?,
        None => 0,
    };
    let exp = exp.checked_add(shift)?;
    buf.clear();
    buf.push_str(&text[..e_at]);
    buf.push('e');
    push_int(buf, exp);
    Some(buf.as_str())
}

/// An exponent `[+-]digits` (at least one digit, at most 9: any larger one overflows a
/// double whatever the mantissa, and is left to the ordinary parse).
fn parse_exp(e: &[u8]) -> Option<i32> {
    let (neg, digits) = match e.first() {
        Some(b'-') => (true, &e[1..]),
        Some(b'+') => (false, &e[1..]),
        _ => (false, e),
    };
    if digits.is_empty() || digits.len() > 9 {
        return None;
    }
    let mut v: i32 = 0;
    for &c in digits {
        if !c.is_ascii_digit() {
            return None;
        }
        v = v * 10 + i32::from(c - b'0');
    }
    Some(if neg { -v } else { v })
}

/// The decimal text of `v`, in `buf`.
fn int_text(v: i32, buf: &mut [u8; 11]) -> &[u8] {
    let mut u = v.unsigned_abs();
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (u % 10) as u8;
        u /= 10;
        if u == 0 {
            break;
        }
    }
    if v < 0 {
        i -= 1;
        buf[i] = b'-';
    }
    &buf[i..]
}

/// Appends the decimal text of `v`.
fn push_int(out: &mut String, v: i32) {
    let mut buf = [0u8; 11];
    for &c in int_text(v, &mut buf) {
        out.push(char::from(c));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // The reference: the first, plainer implementation (digits gathered with slices, then
    // written), which the fast one must match byte for byte.
    /// Room for the digits of ryu's text, zeros included: at most 17 significant digits, and in
    /// its plain form up to 16 zeros before or after them.
    const REF_DIGITS: usize = 40;

    /// A finite decimal: `(-1)^neg × digits × 10^exp`, `digits` (ASCII) without leading or
    /// trailing zeros (empty for zero).
    struct Decimal<'a> {
        neg: bool,
        digits: &'a [u8],
        exp: i32,
    }

    /// Parses ryu's output `-?d+(.d+)?(e-?d+)?` into `buf`: None for anything else (it never is).
    fn parse_ryu<'a>(text: &str, buf: &'a mut [u8; REF_DIGITS]) -> Option<Decimal<'a>> {
        let (neg, body) = match text.strip_prefix('-') {
            Some(b) => (true, b),
            None => (false, text),
        };
        let (mant, exp) = match body.split_once('e') {
            Some((m, e)) => (m, parse_exp(e.as_bytes())?),
            None => (body, 0),
        };
        let (int, frac) = mant.split_once('.').unwrap_or((mant, ""));
        let (int, frac) = (int.as_bytes(), frac.as_bytes());
        let n = int.len() + frac.len();
        if !int.iter().chain(frac).all(u8::is_ascii_digit) {
            return None;
        }
        buf.get_mut(..int.len())?.copy_from_slice(int);
        buf.get_mut(int.len()..n)?.copy_from_slice(frac);
        let all = &buf[..n];
        let start = all.iter().position(|&c| c != b'0').unwrap_or(n);
        let end = all
            .iter()
            .rposition(|&c| c != b'0')
            .map_or(start, |i| i + 1);
        let exp = exp
            .checked_sub(i32::try_from(frac.len()).ok()?)?
            .checked_add(i32::try_from(n - end).ok()?)?;
        Some(Decimal {
            neg,
            digits: &buf[start..end],
            exp,
        })
    }

    impl Decimal<'_> {
        /// The text of this decimal times 10^shift: plain within [`PLAIN_EXP`], else
        /// `d.ddde±x`; built on the stack (the writer calls it for every cell). None only if it
        /// would not fit [`Ascii`], which ryu's at most 17 digits never reach.
        fn write(&self, shift: i32) -> Option<Ascii> {
            let mut out = Ascii::default();
            if self.neg {
                out.extend(b"-")?;
            }
            let digits = self.digits;
            if digits.is_empty() {
                out.extend(b"0")?;
                return Some(out);
            }
            let n = i32::try_from(digits.len()).ok()?;
            // Digits before the decimal point, and the power of ten of the leading digit.
            let point = n + self.exp + shift;
            let lead = point - 1;
            if PLAIN_EXP.contains(&lead) {
                if point <= 0 {
                    out.extend(b"0.")?;
                    out.zeros(-point)?;
                    out.extend(digits)?;
                } else if point >= n {
                    out.extend(digits)?;
                    out.zeros(point - n)?;
                } else {
                    let (int, frac) = digits.split_at(usize::try_from(point).ok()?);
                    out.extend(int)?;
                    out.extend(b".")?;
                    out.extend(frac)?;
                }
            } else {
                out.extend(&digits[..1])?;
                if digits.len() > 1 {
                    out.extend(b".")?;
                    out.extend(&digits[1..])?;
                }
                out.extend(b"e")?;
                out.int(lead)?;
            }
            Some(out)
        }
    }

    /// Longest cell text [`Decimal::write`] makes: a sign, `0.`, 8 zeros and 17 digits (28), or
    /// 17 digits and 16 zeros (33), or `d.` 16 digits `e-` and 10 exponent digits (31).
    const ASCII_CAP: usize = 48;

    /// A short ASCII text built on the stack.
    struct Ascii {
        b: [u8; ASCII_CAP],
        n: usize,
    }

    impl Default for Ascii {
        fn default() -> Ascii {
            Ascii {
                b: [0; ASCII_CAP],
                n: 0,
            }
        }
    }

    impl Ascii {
        fn extend(&mut self, s: &[u8]) -> Option<()> {
            self.b.get_mut(self.n..self.n + s.len())?.copy_from_slice(s);
            self.n += s.len();
            Some(())
        }

        fn zeros(&mut self, k: i32) -> Option<()> {
            let k = usize::try_from(k).ok()?;
            self.b.get_mut(self.n..self.n + k)?.fill(b'0');
            self.n += k;
            Some(())
        }

        fn int(&mut self, v: i32) -> Option<()> {
            let mut buf = [0u8; 11];
            self.extend(int_text(v, &mut buf))
        }

        fn as_str(&self) -> Option<&str> {
            std::str::from_utf8(&self.b[..self.n]).ok()
        }
    }

    fn shifted(v: f64, shift: i32) -> String {
        let mut s = String::new();
        push_shifted(&mut s, &mut ryu::Buffer::new(), v, shift);
        s
    }

    #[test]
    fn moves_the_point_of_ryus_digits() {
        assert_eq!(shifted(0.001, 3), "1");
        assert_eq!(shifted(1.5, 3), "1500");
        assert_eq!(shifted(-0.0123, 3), "-12.3");
        assert_eq!(shifted(1.0e-7, 3), "0.0001");
        assert_eq!(shifted(1.25e-12, 3), "0.00000000125");
        assert_eq!(shifted(1.25e-13, 3), "1.25e-10");
        assert_eq!(shifted(2.0e20, 3), "2e23");
        assert_eq!(shifted(0.0, 3), "0");
        assert_eq!(shifted(-0.0, 3), "-0");
        assert_eq!(shifted(123.456, 0), "123.456");
        assert_eq!(shifted(0.1 + 0.2, 3), "300.00000000000004");
    }

    /// The reference path: every value through parse_ryu and Decimal::write.
    fn general(v: f64, shift: i32) -> String {
        let mut ryu = ryu::Buffer::new();
        let mut digits = [0u8; REF_DIGITS];
        parse_ryu(ryu.format_finite(v), &mut digits)
            .and_then(|d| d.write(shift))
            .and_then(|a| a.as_str().map(str::to_owned))
            .unwrap_or_default()
    }

    #[test]
    fn the_one_pass_writer_matches_the_reference() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut checked = 0;
        for i in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let v = match i % 4 {
                0 => f64::from_bits(x),
                1 => (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0,
                2 => ((x >> 40) as f64 - 8.0e6) / 1.0e4,
                _ => (x as f64 / u64::MAX as f64) * 10f64.powi((i % 40) - 20),
            };
            if !v.is_finite() {
                continue;
            }
            for shift in [3, 6, -3] {
                let mut s = String::new();
                push_shifted(&mut s, &mut ryu::Buffer::new(), v, shift);
                assert_eq!(s, general(v, shift), "{v:e} << {shift}");
                checked += 1;
            }
        }
        assert!(checked > 500_000, "{checked} values");
    }

    #[test]
    fn rewrites_the_exponent_of_a_cell() {
        let mut buf = String::new();
        assert_eq!(shift_text("1.5", -3, &mut buf), Some("1.5e-3"));
        assert_eq!(shift_text("-2E+4", -3, &mut buf), Some("-2e1"));
        assert_eq!(shift_text("+.5e-2", -6, &mut buf), Some("+.5e-8"));
        // Not numbers: the rewritten text does not parse either.
        for bad in [
            "inf", "NaN", "infinity", ".", "0x10", "+", "1.2.3", "abc", "",
        ] {
            let t = shift_text(bad, -3, &mut buf).map(str::to_owned);
            assert!(t.is_none_or(|t| t.parse::<f64>().is_err()), "{bad}");
        }
        assert_eq!(shift_text("1e", -3, &mut buf), None);
        assert_eq!(shift_text("1e2147483647", 1, &mut buf), None);
        assert_eq!(shift_text("1e999999999", -3, &mut buf), Some("1e999999996"));
        assert_eq!(shift_text("1e-5", 3, &mut buf), Some("1e-2"));
        assert_eq!(shift_text("1e--5", 3, &mut buf), None);
        assert_eq!(shift_text("1.5e3.0", 3, &mut buf), None);
        assert_eq!(shift_text("1e5e3", 3, &mut buf), None);
        assert_eq!(shift_text("12", 0, &mut buf), Some("12e0"));
        assert_eq!(shift_text("1e-2147483645", -3, &mut buf), None);
        assert_eq!(shift_text("5e-999999999", i32::MIN + 5, &mut buf), None);
        let mut b = [0u8; 11];
        assert_eq!(int_text(i32::MIN, &mut b), b"-2147483648");
        assert_eq!(int_text(0, &mut b), b"0");
        assert_eq!(int_text(-7, &mut b), b"-7");
    }
}
