//! Prints the `strata bench shade` and `strata bench render` reports:
//! `cargo run --release --example bench`.

fn main() {
    match strata::bench::bench_shade(None, None) {
        Ok(report) => println!("{report}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
    match strata::bench::bench_render(None, 16, (64, 64)) {
        Ok(report) => println!("{report}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
