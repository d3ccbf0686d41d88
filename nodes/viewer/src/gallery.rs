//! The gallery: every shown fibre re-centred at its centre of mass and laid out on a 2-D
//! grid (image coordinates: x to the right, y down), one band of rows per case (cases top to
//! bottom in name order), fibres in each band in gallery order (initial layer, then final
//! σ²), filling rows left to right. Each fibre is drawn as its side view (x1 to the right,
//! x2 up).

/// Positions of every gallery cell: `centres[case][rank]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Gallery {
    pub cell_plus: f64,
    pub columns: usize,
    pub centres: Vec<Vec<[f64; 3]>>,
    /// Where each case band's label goes (centred above its first row).
    pub labels: Vec<[f64; 3]>,
}

/// Lays out `counts[case]` fibres per case for fibres up to `longest_plus` long.
/// Columns grow with the total so the grid stays about twice as wide as tall.
pub fn layout(counts: &[usize], longest_plus: f64) -> Gallery {
    let total: usize = counts.iter().sum();
    let columns = ((2.0 * total as f64).sqrt().ceil() as usize).clamp(10, 100);
    let cell = 1.15 * longest_plus.max(1e-9);
    let mut row = 0.0;
    let mut centres = Vec::with_capacity(counts.len());
    let mut labels = Vec::with_capacity(counts.len());
    for &n in counts {
        let width = n.clamp(1, columns) as f64;
        labels.push([0.5 * (width - 1.0) * cell, (row - 0.55) * cell, 0.0]);
        centres.push(
            (0..n)
                .map(|i| {
                    let (r, c) = (i / columns, i % columns);
                    [c as f64 * cell, (row + r as f64) * cell, 0.0]
                })
                .collect(),
        );
        // a one-row gap between case bands, for the next band's label
        row += n.div_ceil(columns).max(1) as f64 + 1.0;
    }
    Gallery {
        cell_plus: cell,
        columns,
        centres,
        labels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_stack_in_order_and_cells_do_not_touch() {
        let g = layout(&[50, 50, 7], 21.0);
        // 107 fibres: ceil(sqrt(214)) = 15 columns
        assert_eq!(g.columns, 15);
        assert!((g.cell_plus - 1.15 * 21.0).abs() < 1e-12);
        let all: Vec<[f64; 3]> = g.centres.iter().flatten().copied().collect();
        assert_eq!(all.len(), 107);
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
                assert!(d >= g.cell_plus - 1e-9, "cells {a:?} and {b:?} overlap");
            }
        }
        // rank order fills a row left to right, then the next row down
        let c = &g.centres[0];
        assert_eq!(c[1][0] - c[0][0], g.cell_plus);
        assert_eq!(c[15][1], c[0][1] + g.cell_plus);
        assert_eq!(c[15][0], c[0][0]);
        // case 0 takes 4 rows (50 / 15), then a row of gap: case 1 starts 5 rows down
        let top = |k: usize| g.centres[k][0][1];
        assert!((top(1) - top(0) - 5.0 * g.cell_plus).abs() < 1e-9);
        assert!((top(2) - top(1) - 5.0 * g.cell_plus).abs() < 1e-9);
        // every band's label sits in the gap above its first row: at least half a cell
        // clear of the fibres' cells (which reach half a cell from their centres) on
        // both sides
        for k in 0..3 {
            assert!(g.labels[k][1] <= top(k) - 0.5 * g.cell_plus);
            if k > 0 {
                let last_row_before = g.centres[k - 1].last().unwrap()[1];
                assert!(g.labels[k][1] >= last_row_before + 1.4 * g.cell_plus);
            }
        }
    }
}
