//! `tessera-service`: the HTTP API, job queue and web page of a Tessera farm, with local
//! workers. See the `tessera_service` library.

fn main() -> std::process::ExitCode {
    tessera_service::main()
}
