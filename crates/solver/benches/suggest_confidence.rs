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

    // Error by confidence band [lo, hi), pooled: the flagged ones, two bands between, and full confidence (the
    // confidence saturates at 1, so quantiles of it would split equal values arbitrarily).
    let flag_below = params.low_confidence_below;
    let bands: [(&str, f64, f64); 4] = [
        ("flagged", f64::NEG_INFINITY, flag_below),
        ("low", flag_below, 0.7),
        ("high", 0.7, 1.0),
        ("full (1)", 1.0, f64::INFINITY),
    ];
    println!();
    println!("| confidence | range | suggestions | median error (mm) | P90 (mm) | max (mm) | > {WRONG_MM} mm |");
    println!("|---|---|---|---|---|---|---|");
    for (name, lo, hi) in bands {
        let errors: Vec<f64> = all.iter().filter(|a| a.0 >= lo && a.0 < hi).map(|a| a.1).collect();
        println!(
            "| {name} | {} | {} | {:.2} | {:.2} | {:.2} | {} |",
            if hi.is_infinite() { "1".to_owned() } else { format!("{:.2}–{hi:.2}", lo.max(0.0)) },
            errors.len(),
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

/// Spearman's rank correlation of the first two fields, equal values sharing their mean rank (the confidence is
/// often exactly 1).
fn spearman(v: &[(f64, f64, bool)]) -> f64 {
    let ranks = |key: &dyn Fn(&(f64, f64, bool)) -> f64| {
        let mut order: Vec<usize> = (0..v.len()).collect();
        order.sort_by(|&a, &b| key(&v[a]).total_cmp(&key(&v[b])));
        let mut rank = vec![0.0; v.len()];
        let mut start = 0;
        while start < order.len() {
            let value = key(&v[order[start]]);
            let end = start + order[start..].iter().take_while(|&&i| key(&v[i]).total_cmp(&value).is_eq()).count();
            for &i in &order[start..end] {
                rank[i] = (start + end - 1) as f64 / 2.0;
            }
            start = end;
        }
        rank
    };
    let (a, b) = (ranks(&|x| x.0), ranks(&|x| x.1));
    let mean = |r: &[f64]| r.iter().sum::<f64>() / r.len() as f64;
    let (ma, mb) = (mean(&a), mean(&b));
    let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let var = |r: &[f64], m: f64| r.iter().map(|x| (x - m).powi(2)).sum::<f64>();
    cov / (var(&a, ma) * var(&b, mb)).sqrt()
}
