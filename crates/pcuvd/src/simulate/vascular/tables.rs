//! The three-table text layout of network blood-flow solvers (e.g. microBlooM): vertices, edges,
//! boundary conditions, as comma-separated text with a header line.
//!
//! * `vertices.csv`: `x_um,y_um,z_um` (or `x_m,y_m,z_m`); row i is vertex i (0-based).
//! * `edges.csv`: `v1,v2,diameter_um,length_um,class` (or `_m`); `length` may be left empty (or
//!   the column left out) for the straight distance; `class` is `arteriole`, `capillary` or
//!   `venule` (`artery`, `vein` also read).
//! * `boundary.csv`: `vertex,type,value[,pulse]`; `type` is `pressure` (value in Pa) or `flow`
//!   (inflow in m³/s, negative for an outflow); `pulse` is the peak-to-trough swing of the
//!   cardiac pulse in the same unit (0 or absent: steady).
//!
//! Columns may come in any order and extra columns are ignored. Blank lines and lines starting
//! with `#` are skipped. Cells are plain: no quoting, so no commas inside a cell.

use std::fmt::Write;

use super::graph::{Boundary, BoundaryKind, Edge, VesselClass, VesselGraph};
use crate::core::error::{Error, Result, invalid};

/// The three tables as text, e.g. to be written to `vertices.csv`, `edges.csv`, `boundary.csv`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tables {
    /// `vertices.csv`.
    pub vertices: String,
    /// `edges.csv`.
    pub edges: String,
    /// `boundary.csv`.
    pub boundary: String,
}

/// The vessel graph held by the three tables' texts (layout in the module docs), validated; an
/// error names the file, line and column of the first bad cell.
pub fn parse_tables(vertices: &str, edges: &str, boundary: &str) -> Result<VesselGraph> {
    let vt = Table::read("vertices.csv", vertices)?;
    let scale = vt.length_scale("x")?;
    let cols: Vec<usize> = ["x", "y", "z"]
        .iter()
        .map(|c| vt.require(&format!("{c}{}", scale.1)))
        .collect::<Result<_>>()?;
    let mut graph = VesselGraph::default();
    for row in &vt.rows {
        let mut p = [0.0; 3];
        for (v, &c) in p.iter_mut().zip(&cols) {
            *v = vt.number(row, c)? * scale.0;
        }
        graph.vertices.push(p);
    }
    let n = graph.vertices.len();

    let et = Table::read("edges.csv", edges)?;
    let scale = et.length_scale("diameter")?;
    let (c1, c2) = (et.require("v1")?, et.require("v2")?);
    let cd = et.require(&format!("diameter{}", scale.1))?;
    let cl = et.find(&format!("length{}", scale.1));
    let cc = et.require("class")?;
    for row in &et.rows {
        let v1 = et.index(row, c1, n)?;
        let v2 = et.index(row, c2, n)?;
        let diameter = et.number(row, cd)? * scale.0;
        if diameter <= 0.0 {
            return Err(et.error(row, cd, "a diameter must be > 0"));
        }
        let length = match cl {
            Some(c) if !row.cells[c].is_empty() => {
                let l = et.number(row, c)? * scale.0;
                if l <= 0.0 {
                    return Err(et.error(row, c, "a length must be > 0 (or empty)"));
                }
                Some(l)
            }
            _ => None,
        };
        let class = VesselClass::from_name(row.cells[cc])
            .ok_or_else(|| et.error(row, cc, "is not arteriole, capillary or venule"))?;
        graph.edges.push(Edge {
            v1,
            v2,
            diameter,
            length,
            class,
        });
    }

    let bt = Table::read("boundary.csv", boundary)?;
    let (cv, ct, cx) = (
        bt.require("vertex")?,
        bt.require("type")?,
        bt.require("value")?,
    );
    let cp = bt.find("pulse");
    for row in &bt.rows {
        let vertex = bt.index(row, cv, n)?;
        let kind = match row.cells[ct].to_ascii_lowercase().as_str() {
            "pressure" => BoundaryKind::Pressure,
            "flow" | "inflow" => BoundaryKind::Inflow,
            _ => return Err(bt.error(row, ct, "is not pressure or flow")),
        };
        let value = bt.number(row, cx)?;
        let pulse = match cp {
            Some(c) if !row.cells[c].is_empty() => bt.number(row, c)?,
            _ => 0.0,
        };
        graph.boundaries.push(Boundary {
            vertex,
            kind,
            value,
            pulse,
        });
    }
    graph.validate()?;
    Ok(graph)
}

/// The three tables of `graph`, in metres and SI units, every number written so that
/// [`parse_tables`] reads back the same bits.
pub fn write_tables(graph: &VesselGraph) -> Tables {
    let mut vertices = String::from("x_m,y_m,z_m\n");
    for p in &graph.vertices {
        let _ = writeln!(vertices, "{:e},{:e},{:e}", p[0], p[1], p[2]);
    }
    let mut edges = String::from("v1,v2,diameter_m,length_m,class\n");
    for e in &graph.edges {
        let length = e.length.map(|l| format!("{l:e}")).unwrap_or_default();
        let _ = writeln!(
            edges,
            "{},{},{:e},{length},{}",
            e.v1,
            e.v2,
            e.diameter,
            e.class.name()
        );
    }
    let mut boundary = String::from("vertex,type,value,pulse\n");
    for b in &graph.boundaries {
        let kind = match b.kind {
            BoundaryKind::Pressure => "pressure",
            BoundaryKind::Inflow => "flow",
        };
        let _ = writeln!(boundary, "{},{kind},{:e},{:e}", b.vertex, b.value, b.pulse);
    }
    Tables {
        vertices,
        edges,
        boundary,
    }
}

/// One data row: its 1-based line number and trimmed cells.
struct Row<'a> {
    line: usize,
    cells: Vec<&'a str>,
}

/// A parsed table: its file kind (for errors), header names (lower case) and rows.
struct Table<'a> {
    kind: &'static str,
    header: Vec<String>,
    rows: Vec<Row<'a>>,
}

impl<'a> Table<'a> {
    fn read(kind: &'static str, text: &'a str) -> Result<Self> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim_start_matches('\u{feff}').trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let Some((_, header)) = lines.next() else {
            return Err(invalid(kind, "is empty: a header line is required"));
        };
        let header: Vec<String> = header
            .split(',')
            .map(|c| c.trim().to_ascii_lowercase())
            .collect();
        let mut rows = vec![];
        for (line, l) in lines {
            let cells: Vec<&str> = l.split(',').map(str::trim).collect();
            if cells.len() != header.len() {
                return Err(invalid(
                    kind,
                    format!(
                        "line {line} has {} cells, the header has {}",
                        cells.len(),
                        header.len()
                    ),
                ));
            }
            rows.push(Row { line, cells });
        }
        Ok(Table { kind, header, rows })
    }

    fn find(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    fn require(&self, name: &str) -> Result<usize> {
        self.find(name).ok_or_else(|| {
            invalid(
                self.kind,
                format!(
                    "line 1 (the header) has no column `{name}` (it has {})",
                    self.header.join(",")
                ),
            )
        })
    }

    /// The unit of the length columns, from the suffix of column `name`: (metres per unit,
    /// suffix).
    fn length_scale(&self, name: &str) -> Result<(f64, &'static str)> {
        for (scale, suffix) in [(1e-6, "_um"), (1.0, "_m")] {
            if self.find(&format!("{name}{suffix}")).is_some() {
                return Ok((scale, suffix));
            }
        }
        Err(invalid(
            self.kind,
            format!(
                "line 1 (the header) has no column `{0}_um` or `{0}_m` (it has {1})",
                name,
                self.header.join(",")
            ),
        ))
    }

    fn error(&self, row: &Row, col: usize, what: &str) -> Error {
        invalid(
            self.kind,
            format!(
                "line {}, column {} ({}): `{}` {what}",
                row.line,
                col + 1,
                self.header[col],
                row.cells[col]
            ),
        )
    }

    fn number(&self, row: &Row, col: usize) -> Result<f64> {
        row.cells[col]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.error(row, col, "is not a finite number"))
    }

    fn index(&self, row: &Row, col: usize, n: usize) -> Result<usize> {
        match row.cells[col].parse::<usize>() {
            Ok(i) if i < n => Ok(i),
            Ok(_) => Err(self.error(
                row,
                col,
                &format!("is not a vertex: there are {n} (0-based)"),
            )),
            Err(_) => Err(self.error(row, col, "is not a vertex index (an integer ≥ 0)")),
        }
    }
}
