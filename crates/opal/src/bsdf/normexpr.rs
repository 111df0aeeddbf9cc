//! Normalisation expressions such as `"(n+A)/B"`: a small recursive-descent parser of
//! arithmetic over the variables `n` (the lobe's exponent), `A`, `B` (constants set by the
//! user or fitted by `opal brdf fit-norm`), the constant `pi`, and decimal numbers, with
//! `+ − * / ^` (`^` binds tightest and is right-associative), unary minus and parentheses.
//!
//! Grammar: `expr := term (('+'|'-') term)*`, `term := unary (('*'|'/') unary)*`,
//! `unary := '-' unary | power`, `power := atom ('^' unary)?`,
//! `atom := number | 'n' | 'A' | 'B' | 'pi' | '(' expr ')'`.
//! Errors name the column and the offending text. Tests: below.

use crate::error::{Error, Result};

#[derive(Clone, Debug, PartialEq)]
enum Node {
    Num(f64),
    N,
    A,
    B,
    Neg(Box<Node>),
    Bin(char, Box<Node>, Box<Node>),
}

/// A parsed normalisation expression `c(n; A, B)`.
#[derive(Clone, Debug, PartialEq)]
pub struct NormExpr {
    src: String,
    root: Node,
}

impl std::fmt::Display for NormExpr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.src)
    }
}

struct Parser<'a> {
    s: &'a [u8],
    pos: usize,
    src: &'a str,
}

impl Parser<'_> {
    fn err(&self, why: String) -> Error {
        Error::invalid(
            format!("normalisation expression \"{}\"", self.src),
            format!("column {}: {why}", self.pos + 1),
        )
    }
    fn skip_ws(&mut self) {
        while self.pos < self.s.len() && self.s[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
    }
    fn peek(&mut self) -> Option<u8> {
        self.skip_ws();
        self.s.get(self.pos).copied()
    }
    fn expr(&mut self) -> Result<Node> {
        let mut l = self.term()?;
        while let Some(c @ (b'+' | b'-')) = self.peek() {
            self.pos += 1;
            let r = self.term()?;
            l = Node::Bin(c as char, Box::new(l), Box::new(r));
        }
        Ok(l)
    }
    fn term(&mut self) -> Result<Node> {
        let mut l = self.unary()?;
        while let Some(c @ (b'*' | b'/')) = self.peek() {
            self.pos += 1;
            let r = self.unary()?;
            l = Node::Bin(c as char, Box::new(l), Box::new(r));
        }
        Ok(l)
    }
    fn unary(&mut self) -> Result<Node> {
        if self.peek() == Some(b'-') {
            self.pos += 1;
            return Ok(Node::Neg(Box::new(self.unary()?)));
        }
        if self.peek() == Some(b'+') {
            self.pos += 1;
            return self.unary();
        }
        self.power()
    }
    fn power(&mut self) -> Result<Node> {
        let base = self.atom()?;
        if self.peek() == Some(b'^') {
            self.pos += 1;
            let e = self.unary()?;
            return Ok(Node::Bin('^', Box::new(base), Box::new(e)));
        }
        Ok(base)
    }
    fn atom(&mut self) -> Result<Node> {
        match self.peek() {
            None => Err(self.err("unexpected end of expression".into())),
            Some(b'(') => {
                self.pos += 1;
                let e = self.expr()?;
                if self.peek() != Some(b')') {
                    return Err(self.err("expected ')'".into()));
                }
                self.pos += 1;
                Ok(e)
            }
            Some(c) if c.is_ascii_digit() || c == b'.' => {
                let start = self.pos;
                while self.pos < self.s.len()
                    && (self.s[self.pos].is_ascii_digit() || self.s[self.pos] == b'.')
                {
                    self.pos += 1;
                }
                // optional exponent: 1e-3, 2.5E+2
                if self.pos < self.s.len() && matches!(self.s[self.pos], b'e' | b'E') {
                    let save = self.pos;
                    self.pos += 1;
                    if self.pos < self.s.len() && matches!(self.s[self.pos], b'+' | b'-') {
                        self.pos += 1;
                    }
                    let d0 = self.pos;
                    while self.pos < self.s.len() && self.s[self.pos].is_ascii_digit() {
                        self.pos += 1;
                    }
                    if self.pos == d0 {
                        self.pos = save;
                    }
                }
                let txt = &self.src[start..self.pos];
                txt.parse::<f64>().map(Node::Num).map_err(|_| {
                    self.pos = start;
                    self.err(format!("bad number '{txt}'"))
                })
            }
            Some(c) if c.is_ascii_alphabetic() || c == b'_' => {
                let start = self.pos;
                while self.pos < self.s.len()
                    && (self.s[self.pos].is_ascii_alphanumeric() || self.s[self.pos] == b'_')
                {
                    self.pos += 1;
                }
                match &self.src[start..self.pos] {
                    "n" => Ok(Node::N),
                    "A" => Ok(Node::A),
                    "B" => Ok(Node::B),
                    "pi" => Ok(Node::Num(std::f64::consts::PI)),
                    other => {
                        self.pos = start;
                        Err(self.err(format!("unknown name '{other}' (allowed: n, A, B, pi)")))
                    }
                }
            }
            Some(c) => Err(self.err(format!("unexpected '{}'", c as char))),
        }
    }
}

impl NormExpr {
    /// Parses an expression; errors say where and why.
    pub fn parse(src: &str) -> Result<Self> {
        let mut p = Parser { s: src.as_bytes(), pos: 0, src };
        if p.peek().is_none() {
            return Err(p.err("empty expression".into()));
        }
        let root = p.expr()?;
        if let Some(c) = p.peek() {
            return Err(p.err(format!("unexpected '{}' after the end of the expression", c as char)));
        }
        Ok(NormExpr { src: src.to_string(), root })
    }

    /// The paper's `(n+A)/B`.
    pub fn paper() -> Self {
        Self::parse("(n+A)/B").expect("valid")
    }

    /// Source text.
    pub fn source(&self) -> &str {
        &self.src
    }

    /// Value at `n` with constants `a`, `b`.
    pub fn eval(&self, n: f64, a: f64, b: f64) -> f64 {
        fn go(x: &Node, n: f64, a: f64, b: f64) -> f64 {
            match x {
                Node::Num(v) => *v,
                Node::N => n,
                Node::A => a,
                Node::B => b,
                Node::Neg(e) => -go(e, n, a, b),
                Node::Bin(op, l, r) => {
                    let (l, r) = (go(l, n, a, b), go(r, n, a, b));
                    match op {
                        '+' => l + r,
                        '-' => l - r,
                        '*' => l * r,
                        '/' => l / r,
                        _ => l.powf(r),
                    }
                }
            }
        }
        go(&self.root, n, a, b)
    }

    /// Whether the expression uses `A` / `B` (the fitter needs at least one free constant).
    pub fn uses(&self) -> (bool, bool) {
        fn go(x: &Node, acc: &mut (bool, bool)) {
            match x {
                Node::A => acc.0 = true,
                Node::B => acc.1 = true,
                Node::Neg(e) => go(e, acc),
                Node::Bin(_, l, r) => {
                    go(l, acc);
                    go(r, acc);
                }
                _ => {}
            }
        }
        let mut acc = (false, false);
        go(&self.root, &mut acc);
        acc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_evaluates() {
        let e = NormExpr::paper();
        assert!((e.eval(10.0, 6.0, 24.55) - 16.0 / 24.55).abs() < 1e-15);
        let e = NormExpr::parse(" (n + 2) / (2*pi) ").unwrap();
        assert!((e.eval(3.0, 0.0, 0.0) - 5.0 / (2.0 * std::f64::consts::PI)).abs() < 1e-15);
        let e = NormExpr::parse("-2^2^3 + 1.5e1 - -A*B").unwrap();
        assert_eq!(e.eval(0.0, 2.0, 3.0), -256.0 + 15.0 + 6.0);
        assert_eq!(NormExpr::parse("n/B*A").unwrap().eval(8.0, 3.0, 2.0), 12.0);
        assert_eq!(NormExpr::parse("(n+A)/B").unwrap().uses(), (true, true));
        assert_eq!(NormExpr::parse("n/8").unwrap().uses(), (false, false));
    }

    #[test]
    fn rejects_bad_input_with_position() {
        for (s, col) in
            [("(n+A", 5), ("n+", 3), ("n*x", 3), ("", 1), ("(n+A)/B)", 8), ("2..3", 1), ("n $ 2", 3)]
        {
            let e = NormExpr::parse(s).unwrap_err().to_string();
            assert!(e.contains(&format!("column {col}")), "{s}: {e}");
        }
    }
}
