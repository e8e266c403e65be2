//! `svpack` command line: parses options, calls the library, prints.
//!
//! Exit codes: 0 success, 1 input or usage error, 2 validation failure.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use svpack::build::{BuildConfig, build_file};
use svpack::layout::{DEFAULT_MAX_MULT, MAX_MAX_MULT};
use svpack::report::Summary;

/// Silhouette shadow-volume geometry for WebGL 1 (Milet et al. 2015).
#[derive(Parser)]
#[command(name = "svpack", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build a .svpk file from a glTF 2.0 (.gltf/.glb) or OBJ file.
    Build {
        /// Input .gltf, .glb or .obj file.
        input: PathBuf,
        /// Output .svpk file (written atomically).
        #[arg(short, long)]
        output: PathBuf,
        /// K: most opposite vertices per side instance; edges with more are
        /// split. The sides shader needs 3 + K vertex attributes; the default 5
        /// fits the 8 every WebGL 1 device has.
        #[arg(long, default_value_t = DEFAULT_MAX_MULT,
              value_parser = clap::value_parser!(u32).range(1..=MAX_MAX_MULT as i64))]
        max_mult: u32,
        /// Wrap the file in a zstd frame (readers detect it).
        #[arg(long)]
        compress: bool,
        /// Print the summary as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Read a .svpk file back, check it, and report what it holds.
    Inspect {
        /// The .svpk file.
        file: PathBuf,
        /// Print the summary as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
}

fn print_summary(s: &Summary, json: bool) {
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(s).expect("summary serialises")
        );
    } else {
        print!("{}", s.to_text());
    }
}

fn run(cli: Cli) -> Result<(), svpack::error::Error> {
    match cli.command {
        Command::Build {
            input,
            output,
            max_mult,
            compress,
            json,
        } => {
            let out = build_file(&input, &output, &BuildConfig { max_mult, compress })?;
            for w in &out.warnings {
                eprintln!("warning: {}: {w}", input.display());
            }
            let mut s = Summary::from_header(&out.header, out.file_bytes, compress);
            s.time_ms = Some(out.elapsed.as_secs_f64() * 1e3);
            s.warnings = out.warnings;
            if !json {
                println!("{} -> {}", input.display(), output.display());
            }
            print_summary(&s, json);
        }
        Command::Inspect { file, json } => {
            let f = svpack::format::read_file(&file)?;
            let s = Summary::from_header(&f.header, f.file_bytes, f.compressed);
            if !json {
                println!(
                    "{}: svpk {}.{}, written by {}",
                    file.display(),
                    svpack::format::VERSION_MAJOR,
                    f.version_minor,
                    f.header.generator
                );
            }
            print_summary(&s, json);
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap uses exit code 2 for usage errors; 2 is reserved for
            // validation failures here, so usage errors exit with 1.
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}
