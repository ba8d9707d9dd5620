//! Writes the fuzzing seeds as cargo-fuzz corpora: `cargo run --release -p pc-fuzz --example
//! corpus -- fuzz/corpus` (docs/artifacts.md, "Fuzzing").

fn main() {
    let root = std::env::args_os()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| "fuzz/corpus".into());
    match pc_fuzz::seeds::write_corpus(&root) {
        Ok(files) => println!("wrote {} seed files under {}", files.len(), root.display()),
        Err(e) => {
            eprintln!("corpus: {}: {e}", root.display());
            std::process::exit(1);
        }
    }
}
