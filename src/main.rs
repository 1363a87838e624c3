//! `scatterlab`: the thin binary. Everything lives in the library (`scatterlab::cli`).

fn main() {
    std::process::exit(scatterlab::cli::main());
}
