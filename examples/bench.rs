//! Prints the `strata bench shade` and `strata bench render` reports:
//! `cargo run --release --example bench [shade|render]` (both when no argument is given).

fn main() {
    let which = std::env::args().nth(1).unwrap_or_default();
    let mut reports = Vec::new();
    if which != "render" {
        reports.push(strata::bench::bench_shade(None, None));
    }
    if which != "shade" {
        reports.push(strata::bench::bench_render(None, 16, (64, 64)));
    }
    for report in reports {
        match report {
            Ok(text) => println!("{text}"),
            Err(e) => {
                eprintln!("error: {e}");
                std::process::exit(1);
            }
        }
    }
}
