//! Hadamard matrices: the polarity code of pulse-coded plane-wave transmission.
//!
//! Row i of H_n gives the polarities of the n pulse slots in transmit event i of a compound frame.
//! Powers of two use Sylvester's construction (so H_4 is the paper's eq. 1); other orders use
//! Paley's first construction (n − 1 a prime ≡ 3 mod 4), Paley's second (n/2 − 1 a prime ≡ 1 mod 4),
//! or Sylvester doubling of a smaller order.

use crate::core::error::{Error, Result};

/// An n × n matrix of ±1 whose rows are mutually orthogonal (H·Hᵀ = n·I).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hadamard {
    order: usize,
    /// Row-major ±1 entries.
    entries: Vec<i8>,
}

impl Hadamard {
    /// The Hadamard matrix of order `n`, or [`Error::HadamardOrder`] when pcuvd has no construction for it.
    pub fn new(n: usize) -> Result<Self> {
        let rows = build(n).ok_or(Error::HadamardOrder(n))?;
        Ok(Hadamard {
            order: n,
            entries: rows.into_iter().flatten().collect(),
        })
    }

    /// Order n (number of rows, columns, pulse slots and events per compound frame).
    pub fn order(&self) -> usize {
        self.order
    }

    /// Entry (row, col) as ±1.
    #[inline]
    pub fn get(&self, row: usize, col: usize) -> f32 {
        self.entries[row * self.order + col] as f32
    }

    /// Row `i`: the polarities of the pulse slots fired in event i of a compound frame.
    pub fn row(&self, i: usize) -> &[i8] {
        &self.entries[i * self.order..(i + 1) * self.order]
    }
}

fn is_prime(q: usize) -> bool {
    q >= 2
        && (2..)
            .take_while(|d| d * d <= q)
            .all(|d| !q.is_multiple_of(d))
}

/// Legendre symbol χ(a) over the prime field F_q: 0, +1 (quadratic residue) or −1.
fn legendre(a: usize, q: usize) -> i8 {
    let a = a % q;
    if a == 0 {
        return 0;
    }
    // Euler's criterion: a^((q-1)/2) mod q.
    let (mut base, mut exp, mut acc) = (a as u64, (q - 1) / 2, 1u64);
    while exp > 0 {
        if exp & 1 == 1 {
            acc = acc * base % q as u64;
        }
        base = base * base % q as u64;
        exp >>= 1;
    }
    if acc == 1 { 1 } else { -1 }
}

/// Jacobsthal matrix Q[i][j] = χ(j − i) over F_q.
fn jacobsthal(q: usize) -> Vec<Vec<i8>> {
    (0..q)
        .map(|i| (0..q).map(|j| legendre(j + q - i, q)).collect())
        .collect()
}

fn build(n: usize) -> Option<Vec<Vec<i8>>> {
    match n {
        0 => None,
        1 => Some(vec![vec![1]]),
        2 => Some(vec![vec![1, 1], vec![1, -1]]),
        _ if !n.is_multiple_of(4) => None,
        _ if n.is_power_of_two() => build(n / 2).map(|h| sylvester_double(&h)),
        _ if is_prime(n - 1) && (n - 1) % 4 == 3 => Some(paley_one(n - 1)),
        _ if is_prime(n / 2 - 1) && (n / 2 - 1) % 4 == 1 => Some(paley_two(n / 2 - 1)),
        _ => build(n / 2).map(|h| sylvester_double(&h)),
    }
}

/// [[H, H], [H, −H]].
fn sylvester_double(h: &[Vec<i8>]) -> Vec<Vec<i8>> {
    let top = h.iter().map(|r| [r.as_slice(), r.as_slice()].concat());
    let bottom = h
        .iter()
        .map(|r| r.iter().copied().chain(r.iter().map(|v| -v)).collect());
    top.chain(bottom).collect()
}

/// Paley I, order q + 1 for a prime q ≡ 3 (mod 4): H = I + [[0, 1ᵀ], [−1, Q]].
fn paley_one(q: usize) -> Vec<Vec<i8>> {
    let jq = jacobsthal(q);
    let n = q + 1;
    let mut h = vec![vec![0i8; n]; n];
    for (i, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            let c = match (i, j) {
                (0, 0) => 0,
                (0, _) => 1,
                (_, 0) => -1,
                _ => jq[i - 1][j - 1],
            };
            *v = c + i8::from(i == j);
        }
    }
    h
}

/// Paley II, order 2(q + 1) for a prime q ≡ 1 (mod 4), from the symmetric conference matrix C.
fn paley_two(q: usize) -> Vec<Vec<i8>> {
    let jq = jacobsthal(q);
    let m = q + 1;
    let conference = |i: usize, j: usize| -> i8 {
        match (i, j) {
            (0, 0) => 0,
            (0, _) | (_, 0) => 1,
            _ => jq[i - 1][j - 1],
        }
    };
    let mut h = vec![vec![0i8; 2 * m]; 2 * m];
    for i in 0..m {
        for j in 0..m {
            // 0 → [[1, −1], [−1, −1]], ±1 → ±[[1, 1], [1, −1]].
            let block = match conference(i, j) {
                0 => [[1, -1], [-1, -1]],
                s => [[s, s], [s, -s]],
            };
            for a in 0..2 {
                for b in 0..2 {
                    h[2 * i + a][2 * j + b] = block[a][b];
                }
            }
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_orthogonal(h: &Hadamard) {
        let n = h.order();
        for i in 0..n {
            for j in 0..n {
                let dot: f32 = (0..n).map(|k| h.get(i, k) * h.get(j, k)).sum();
                let expect = if i == j { n as f32 } else { 0.0 };
                assert_eq!(dot, expect, "order {n}, rows {i},{j}");
            }
        }
    }

    #[test]
    fn required_orders_are_orthogonal() {
        for n in [1, 2, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40, 44, 48, 64] {
            let h = Hadamard::new(n).unwrap_or_else(|e| panic!("{e}"));
            assert!(h.entries.iter().all(|&v| v == 1 || v == -1));
            assert_orthogonal(&h);
        }
    }

    #[test]
    fn order_four_is_the_papers() {
        let h = Hadamard::new(4).unwrap();
        let expect: [[i8; 4]; 4] = [[1, 1, 1, 1], [1, -1, 1, -1], [1, 1, -1, -1], [1, -1, -1, 1]];
        for (i, row) in expect.iter().enumerate() {
            assert_eq!(h.row(i), row);
        }
    }

    #[test]
    fn impossible_orders_are_errors() {
        for n in [0, 3, 5, 6, 7, 10, 18] {
            assert_eq!(Hadamard::new(n), Err(Error::HadamardOrder(n)));
        }
    }
}
