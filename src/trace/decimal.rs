//! Exact decimal shifts: a number's text multiplied by a power of ten by moving its decimal
//! point, never by float arithmetic.
//!
//! The writer takes the shortest round-trip text of an SI value (ryu) and moves its point to
//! the display unit (m → mm: three places right). The reader moves it back and parses with
//! `f64::from_str`, which rounds correctly; the text it parses is then exactly the decimal
//! ryu produced, which reads back as the original value. So `v` written in mm and read back
//! is `v`, bit for bit, where `m_to_mm` then `mm_to_m` may be an ulp off.

use std::fmt::Write as _;

/// Significant digits kept from ryu's text: it never gives more than 17, zeros between them
/// included; leading and trailing zeros go into the exponent.
const MAX_DIGITS: usize = 24;
/// Plain decimal (no exponent) when the leading digit's power of ten lies in this range,
/// scientific notation outside: `0.000000001` and `123456789012345` are read more easily than
/// with an exponent, `1e-20` and `1e300` are shorter with one.
const PLAIN_EXP: std::ops::RangeInclusive<i32> = -9..=15;

/// A finite decimal: `(-1)^neg × digits × 10^exp`, `digits` without leading or trailing zeros
/// (empty for zero).
struct Decimal {
    neg: bool,
    digits: [u8; MAX_DIGITS],
    n: usize,
    exp: i32,
}

impl Decimal {
    /// Parses ryu's output: `-?d+(.d+)?(e-?d+)?`. None for anything else (it never is).
    fn parse(text: &str) -> Option<Decimal> {
        let (neg, body) = match text.strip_prefix('-') {
            Some(b) => (true, b),
            None => (false, text),
        };
        let (mant, exp) = match body.split_once(['e', 'E']) {
            Some((m, e)) => (m, e.parse::<i32>().ok()?),
            None => (body, 0),
        };
        let mut d = Decimal {
            neg,
            digits: [0; MAX_DIGITS],
            n: 0,
            exp,
        };
        let (mut zeros, mut frac, mut seen_point) = (0i32, 0i32, false);
        for c in mant.bytes() {
            match c {
                b'.' if !seen_point => seen_point = true,
                b'0'..=b'9' => {
                    if seen_point {
                        frac += 1;
                    }
                    if c == b'0' {
                        // Held back: leading zeros vanish, trailing ones go into the exponent.
                        if d.n > 0 {
                            zeros += 1;
                        }
                        continue;
                    }
                    for _ in 0..zeros {
                        d.push(0)?;
                    }
                    zeros = 0;
                    d.push(c - b'0')?;
                }
                _ => return None,
            }
        }
        d.exp = d.exp.checked_add(zeros)?.checked_sub(frac)?;
        Some(d)
    }

    fn push(&mut self, digit: u8) -> Option<()> {
        *self.digits.get_mut(self.n)? = digit;
        self.n += 1;
        Some(())
    }

    /// Appends the text of this decimal times 10^shift: plain within [`PLAIN_EXP`], else
    /// `d.ddde±x`.
    fn write(&self, out: &mut String, shift: i32) {
        if self.neg {
            out.push('-');
        }
        let digits = &self.digits[..self.n];
        if digits.is_empty() {
            out.push('0');
            return;
        }
        let digit = |d: &u8| char::from(b'0' + d);
        let n = self.n as i32;
        // Digits before the decimal point, and the power of ten of the leading digit.
        let point = n + self.exp + shift;
        let lead = point - 1;
        if PLAIN_EXP.contains(&lead) {
            if point <= 0 {
                out.push_str("0.");
                out.extend(std::iter::repeat_n('0', (-point) as usize));
                out.extend(digits.iter().map(digit));
            } else if point >= n {
                out.extend(digits.iter().map(digit));
                out.extend(std::iter::repeat_n('0', (point - n) as usize));
            } else {
                let (int, frac) = digits.split_at(point as usize);
                out.extend(int.iter().map(digit));
                out.push('.');
                out.extend(frac.iter().map(digit));
            }
        } else {
            out.push(digit(&digits[0]));
            if digits.len() > 1 {
                out.push('.');
                out.extend(digits[1..].iter().map(digit));
            }
            // Writing to a String cannot fail.
            let _ = write!(out, "e{lead}");
        }
    }
}

/// Appends to `out` the text of the finite value `v` times 10^`shift`, exactly: ryu's
/// shortest round-trip digits with the decimal point moved. `shift` 0 appends ryu's text as
/// it is.
pub(crate) fn push_shifted(out: &mut String, ryu: &mut ryu::Buffer, v: f64, shift: i32) {
    let text = ryu.format_finite(v);
    if shift == 0 {
        out.push_str(text);
        return;
    }
    match Decimal::parse(text) {
        Some(d) => d.write(out, shift),
        // Not reached (ryu's grammar is the one parsed); the unshifted text is still a number.
        None => out.push_str(text),
    }
}

/// `text`, a decimal number `[+-]digits[.digits][e[+-]digits]`, times 10^`shift`, rewritten
/// into `buf` by moving its exponent, for `f64::from_str` to round once. None when `text` is
/// not of that form (inf, NaN, other text) or the exponent overflows: the caller parses it
/// as it is.
pub(crate) fn shift_text<'a>(text: &str, shift: i32, buf: &'a mut String) -> Option<&'a str> {
    let (mant, exp) = match text.find(['e', 'E']) {
        Some(i) => (&text[..i], text[i + 1..].parse::<i32>().ok()?),
        None => (text, 0),
    };
    let body = mant.strip_prefix(['+', '-']).unwrap_or(mant);
    let digits_only = body.bytes().all(|c| c.is_ascii_digit() || c == b'.');
    if !digits_only || !body.bytes().any(|c| c.is_ascii_digit()) {
        return None;
    }
    let exp = exp.checked_add(shift)?;
    buf.clear();
    buf.push_str(mant);
    // Writing to a String cannot fail.
    let _ = write!(buf, "e{exp}");
    Some(buf.as_str())
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn rewrites_the_exponent_of_a_cell() {
        let mut buf = String::new();
        assert_eq!(shift_text("1.5", -3, &mut buf), Some("1.5e-3"));
        assert_eq!(shift_text("-2E+4", -3, &mut buf), Some("-2e1"));
        assert_eq!(shift_text("+.5e-2", -6, &mut buf), Some("+.5e-8"));
        assert_eq!(shift_text("inf", -3, &mut buf), None);
        assert_eq!(shift_text("NaN", -3, &mut buf), None);
        assert_eq!(shift_text("1e", -3, &mut buf), None);
        assert_eq!(shift_text(".", -3, &mut buf), None);
        assert_eq!(shift_text("1e2147483647", 1, &mut buf), None);
        assert_eq!(shift_text("0x10", -3, &mut buf), None);
    }
}
