//! `tessera-service`, built inside the test crate (see Cargo.toml).

fn main() -> std::process::ExitCode {
    tessera_service::main()
}
