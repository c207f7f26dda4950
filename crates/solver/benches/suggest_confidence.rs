//! How well the suggested targets' confidence predicts their error (issue 18 item 2), over several point seeds of
//! the synthetic head case of `tests/suggest.rs`, and the time per suggestion. Not a criterion bench: one pass,
//! printing Markdown tables for docs/accuracy.md.
//!
//! `cargo bench -p warpbench-solver --bench suggest_confidence [-- SEED ...]` (default seeds 1 to 8)

#[path = "../tests/suggest_case/mod.rs"]
mod suggest_case;

use std::time::Instant;

use suggest_case::{Case, Measured, POINTS, Summary, WRONG_MM, quantile};
use warpbench_solver::suggest::SuggestParams;

fn main() {
    // `cargo bench` passes `--bench`; anything that parses as a number is a seed.
    let mut seeds: Vec<u64> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    if seeds.is_empty() {
        seeds = (1..=8).collect();
    }
    let built = Instant::now();
    let case = Case::build();
    eprintln!("case built in {:.1} s", built.elapsed().as_secs_f64());
    let params = SuggestParams::default();

    println!("{}", Summary::header("seed, fixed contrast"));
    let mut all: Vec<(f64, f64, bool)> = Vec::new();
    let mut ms_each = Vec::new();
    let (mut runs, mut runs_ordered) = (0, 0);
    for &seed in &seeds {
        let points = case.points(POINTS, seed);
        for (name, fixed) in [("same", &case.fixed), ("remapped", &case.fixed_remapped)] {
            let t = Instant::now();
            let measured: Vec<Measured> = case.measure(fixed, &points, &params);
            ms_each.push(1e3 * t.elapsed().as_secs_f64() / points.len() as f64);
            let summary = Summary::of(&measured);
            println!("{}", summary.row(&format!("{seed}, {name}")));
            if summary.flagged > 0 && summary.flagged < measured.len() {
                runs += 1;
                runs_ordered += usize::from(summary.median_flagged_mm > summary.median_unflagged_mm);
            }
            all.extend(measured.iter().map(|m| (m.suggestion.confidence, m.error_mm, m.suggestion.low_confidence)));
        }
    }

    let wrong = all.iter().filter(|a| a.1 > WRONG_MM).count();
    let wrong_flagged = all.iter().filter(|a| a.1 > WRONG_MM && a.2).count();
    let flagged = all.iter().filter(|a| a.2).count();
    println!();
    println!(
        "{} suggestions over seeds {seeds:?}: {wrong} off by more than {WRONG_MM} mm, {wrong_flagged} of them \
         flagged; {flagged} flagged in all ({:.1} %); flagged median error above the unflagged one in {runs_ordered} \
         of {runs} runs with both; Spearman rank correlation of confidence and error {:.2}",
        all.len(),
        100.0 * flagged as f64 / all.len() as f64,
        spearman(&all),
    );

    // Error by confidence quartile, pooled.
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    println!();
    println!("| confidence quartile | confidence | median error (mm) | P90 (mm) | max (mm) | > {WRONG_MM} mm |");
    println!("|---|---|---|---|---|---|");
    let n = all.len();
    for q in 0..4 {
        let part = &all[q * n / 4..(q + 1) * n / 4];
        let errors: Vec<f64> = part.iter().map(|a| a.1).collect();
        println!(
            "| {} | {:.3}–{:.3} | {:.2} | {:.2} | {:.2} | {} |",
            ["lowest", "second", "third", "highest"][q],
            part.first().map_or(f64::NAN, |a| a.0),
            part.last().map_or(f64::NAN, |a| a.0),
            quantile(&errors, 0.5),
            quantile(&errors, 0.9),
            errors.iter().copied().fold(0.0, f64::max),
            errors.iter().filter(|&&e| e > WRONG_MM).count(),
        );
    }
    println!();
    println!(
        "time per suggestion (one thread): median {:.1} ms over {} runs of {POINTS}",
        quantile(&ms_each, 0.5),
        ms_each.len()
    );
}

/// Spearman's rank correlation of the first two fields (ties ranked by position; confidences and errors are
/// continuous).
fn spearman(v: &[(f64, f64, bool)]) -> f64 {
    let ranks = |key: &dyn Fn(&(f64, f64, bool)) -> f64| {
        let mut order: Vec<usize> = (0..v.len()).collect();
        order.sort_by(|&a, &b| key(&v[a]).total_cmp(&key(&v[b])));
        let mut rank = vec![0.0; v.len()];
        for (r, &i) in order.iter().enumerate() {
            rank[i] = r as f64;
        }
        rank
    };
    let (a, b) = (ranks(&|x| x.0), ranks(&|x| x.1));
    let mean = (v.len() as f64 - 1.0) / 2.0;
    let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - mean) * (y - mean)).sum();
    let var: f64 = a.iter().map(|x| (x - mean).powi(2)).sum();
    cov / var
}
