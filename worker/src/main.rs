//! `tessera-worker`: joins a Tessera farm. See the `tessera_worker` library.

fn main() -> std::process::ExitCode {
    tessera_worker::main()
}
