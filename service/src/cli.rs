//! The `ppfd` command line: flags that mirror the TOML configuration.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use clap::Parser;

use crate::config::DaemonConfig;
use crate::engine::DetectionEngine;
use crate::error::{Error, Result};

/// The ppfd daemon: holds PPF object models in memory and answers detect requests over
/// iceoryx2 shared memory. Stops cleanly on SIGINT, SIGTERM or SIGHUP. Logs go to stderr (`RUST_LOG`).
#[derive(Debug, Parser)]
#[command(name = "ppfd", version)]
pub struct Args {
    /// Directory of models: `*.ppfm` files, and PLY meshes (`obj_<id>.ply`) to build models from.
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// TOML configuration file; flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Where models built from PLY meshes are saved (default: $PPFD_CACHE, $XDG_CACHE_HOME/ppfd,
    /// ~/.cache/ppfd, else ppfd-cache in $TMPDIR or /tmp; shared with `ppf eval`); one is reused
    /// while its mesh is unchanged.
    #[arg(long)]
    pub model_cache: Option<PathBuf>,
    /// iceoryx2 resource prefix, ending with '_' (cell1_): daemons (and their clients) with
    /// different prefixes never see each other [default: PPFD_PREFIX, as for the clients, else
    /// the config file's, else iceoryx2's].
    #[arg(long)]
    pub prefix: Option<String>,
    /// Detection worker threads, 0 to 4 per core (0: one per core) [default: 0].
    #[arg(long)]
    pub workers: Option<usize>,
    /// Detections running at once, 1 to 4 per core [default: 1].
    #[arg(long)]
    pub parallel_detections: Option<usize>,
    /// Waiting requests beyond which new ones are refused "busy", 1 to 4096 [default: 64].
    #[arg(long)]
    pub queue_capacity: Option<usize>,
    /// Camera frames older than this are refused "camera stale", milliseconds, 1 to 3600000
    /// [default: 1000].
    #[arg(long)]
    pub max_frame_age_ms: Option<u64>,
    /// Period of camera discovery and dead-process cleanup, milliseconds, 1 to 60000
    /// [default: 1000].
    #[arg(long)]
    pub housekeeping_ms: Option<u64>,
    /// A camera without a driver this long is forgotten (its subscription and shared memory let
    /// go; requests naming it are refused "unknown camera" until it is back), milliseconds, at
    /// most 86400000 [default: 60000].
    #[arg(long)]
    pub forget_camera_after_ms: Option<u64>,
    /// The largest frame detected in, pixels; a larger one is refused "invalid frame"
    /// (a detection takes about 95 bytes per pixel), 1 to 268435456 [default: 16777216].
    #[arg(long)]
    pub max_frame_pixels: Option<u64>,
    /// Set a detector parameter, `stage.field=value` (as `ppf detect --set`, e.g.
    /// `--set voting.reference_step=4`), after the file's `[detector]` table; repeatable.
    #[arg(long = "set", value_name = "STAGE.FIELD=VALUE")]
    pub set: Vec<String>,
}

impl Args {
    /// The configuration: defaults, then the file, then `PPFD_PREFIX`, then the flags.
    pub fn config(&self) -> Result<DaemonConfig> {
        self.config_with(ppfd_protocol::services::prefix_from_env())
    }

    /// [`Args::config`] with `env_prefix` as `PPFD_PREFIX`'s value.
    fn config_with(&self, env_prefix: Option<String>) -> Result<DaemonConfig> {
        let mut c = match &self.config {
            Some(path) => DaemonConfig::from_toml_file(path)?,
            None => DaemonConfig::default(),
        };
        if self.models.is_some() {
            c.models = self.models.clone();
        }
        if self.model_cache.is_some() {
            c.model_cache = self.model_cache.clone();
        }
        // The clients' variable too: `PPFD_PREFIX=cell2_ ppfd` and `PPFD_PREFIX=cell2_ ppf
        // detect` meet. The flag wins over the variable, the variable over the file.
        let prefix = ppfd_protocol::services::prefix_or(self.prefix.as_deref(), || env_prefix)
            .map_err(|e| Error::Prefix(e.to_string()))?;
        if prefix.is_some() {
            c.prefix = prefix;
        }
        c.workers = self.workers.unwrap_or(c.workers);
        c.parallel_detections = self.parallel_detections.unwrap_or(c.parallel_detections);
        c.queue_capacity = self.queue_capacity.unwrap_or(c.queue_capacity);
        c.max_frame_age_ms = self.max_frame_age_ms.unwrap_or(c.max_frame_age_ms);
        c.housekeeping_ms = self.housekeeping_ms.unwrap_or(c.housekeeping_ms);
        c.forget_camera_after_ms = self
            .forget_camera_after_ms
            .unwrap_or(c.forget_camera_after_ms);
        c.max_frame_pixels = self.max_frame_pixels.unwrap_or(c.max_frame_pixels);
        for assignment in &self.set {
            let (key, value) = assignment
                .split_once('=')
                .ok_or_else(|| Error::SetSyntax(assignment.clone()))?;
            c.detector.push((key.trim().to_string(), value.to_string()));
        }
        c.validate()?;
        Ok(c)
    }
}

/// The most characters of iceoryx2's `origin` field: it logs its port's whole state there with
/// each message (8.8 kB on one line for a frame lost from a driver that died).
const MAX_ORIGIN_CHARS: usize = 240;

/// The most characters of any other field's value: the daemon's own errors, whose advice comes
/// last (a mesh in metres is told the `--scale` to build it with), are kept whole.
const MAX_FIELD_CHARS: usize = 4000;

/// Writes one logged field; a value other than the message is cut to [`MAX_ORIGIN_CHARS`] or
/// [`MAX_FIELD_CHARS`] characters.
fn write_field(
    w: &mut tracing_subscriber::fmt::format::Writer<'_>,
    field: &tracing::field::Field,
    value: &dyn std::fmt::Debug,
) -> std::fmt::Result {
    if field.name() == "message" {
        return write!(w, "{value:?}");
    }
    if field.name().starts_with("log.") {
        // What the `log` bridge adds (target, file, line), as the default format leaves out.
        return Ok(());
    }
    let text = format!("{value:?}");
    let most = match field.name() {
        "origin" => MAX_ORIGIN_CHARS,
        _ => MAX_FIELD_CHARS,
    };
    match text.char_indices().nth(most) {
        Some((at, _)) => write!(w, "{}={} …", field.name(), &text[..at]),
        None => write!(w, "{}={text}", field.name()),
    }
}

/// Logs to stderr, filtered by `RUST_LOG` (default `info`).
pub fn init_tracing() {
    use tracing_subscriber::field::MakeExt;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .fmt_fields(tracing_subscriber::fmt::format::debug_fn(write_field).delimited(" "))
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // Colour codes only for a terminal: a log file or journal gets plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}

/// How the daemon gets its engine, from its configuration (the detector's parameters among it).
pub type EngineFactory = dyn FnOnce(&DaemonConfig) -> Result<Arc<dyn DetectionEngine>>;

/// Parses the command line and runs the daemon with the engine `make_engine` builds from the
/// configuration. Prints one line, `ppfd ready pid=<pid> models=<n> failed=<n>` (the models
/// folder's files that did not load), on stdout once it serves (scripts wait for it).
pub fn main(make_engine: Box<EngineFactory>) -> ExitCode {
    main_with_args(std::env::args_os(), make_engine)
}

/// As [`main`], with the command line given (the first item is the program name).
pub fn main_with_args<I, T>(args: I, make_engine: Box<EngineFactory>) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let args = match Args::try_parse_from(args) {
        Ok(a) => a,
        Err(e) => e.exit(),
    };
    init_tracing();
    let config = match args.config() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("ppfd: {e}");
            return ExitCode::from(2);
        }
    };
    // A models folder that cannot be listed is a bad setting too, found before the daemon
    // takes its services.
    if let Some(dir) = &config.models {
        if let Err(source) = std::fs::read_dir(dir) {
            let e = crate::Error::ModelDirectory {
                path: dir.clone(),
                source,
            };
            eprintln!("ppfd: {e}");
            return ExitCode::from(2);
        }
    }
    let engine = match make_engine(&config) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("ppfd: {e}");
            return ExitCode::from(2);
        }
    };
    for (key, value) in &config.detector {
        tracing::info!("detector parameter {key} = {value}");
    }
    let result = crate::daemon::run(config, engine, |ready| {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        let _ = writeln!(
            out,
            "ppfd ready pid={} models={} failed={}",
            ready.pid, ready.models, ready.failed
        );
        let _ = out.flush();
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("ppfd: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The defaults the help names are the configuration's.
    #[test]
    fn help_names_the_defaults() {
        use clap::CommandFactory;
        let d = DaemonConfig::default();
        let mut command = Args::command();
        let help = command.render_help().to_string();
        for (flag, value) in [
            ("--workers", d.workers as u64),
            ("--parallel-detections", d.parallel_detections as u64),
            ("--queue-capacity", d.queue_capacity as u64),
            ("--max-frame-age-ms", d.max_frame_age_ms),
            ("--housekeeping-ms", d.housekeeping_ms),
            ("--forget-camera-after-ms", d.forget_camera_after_ms),
            ("--max-frame-pixels", d.max_frame_pixels),
        ] {
            let at = help
                .find(flag)
                .unwrap_or_else(|| panic!("{flag} in {help}"));
            let rest = &help[at..];
            let next = rest[2..].find("--").map_or(rest.len(), |i| i + 2);
            assert!(
                rest[..next].contains(&format!("[default: {value}]")),
                "{flag}: {}",
                &rest[..next]
            );
        }
    }

    /// iceoryx2's long `origin` is cut; the message, an error of the daemon's and short fields
    /// are whole, and any field beyond [`MAX_FIELD_CHARS`] is cut.
    #[test]
    fn long_logged_values_are_cut() {
        use tracing_subscriber::field::MakeExt;
        let buffer = crate::test_log::Buffer::default();
        let out = buffer.clone();
        let subscriber = tracing_subscriber::fmt()
            .fmt_fields(tracing_subscriber::fmt::format::debug_fn(write_field).delimited(" "))
            .with_writer(move || out.clone())
            .with_ansi(false)
            .finish();
        let message = "m".repeat(300);
        let origin = "o".repeat(5000);
        let error = format!("{} (`ppf model build --scale 1000`)", "e".repeat(400));
        let huge = "h".repeat(MAX_FIELD_CHARS + 10);
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!(origin = %origin, camera = "left", error = %error, "{message}");
            tracing::warn!(reason = %huge, "second");
        });
        let text = buffer.text();
        let (line, second) = text.split_once('\n').unwrap();
        assert!(line.contains(&message), "{line}");
        assert!(line.contains("camera=\"left\""), "{line}");
        assert!(line.contains(&format!("error={error}")), "{line}");
        assert!(
            line.contains(&format!("origin={} …", "o".repeat(MAX_ORIGIN_CHARS))),
            "{line}"
        );
        assert!(line.len() < 1200, "{} bytes", line.len());
        assert!(
            second.contains(&format!("reason={} …", "h".repeat(MAX_FIELD_CHARS))),
            "{second}"
        );
    }

    /// The prefix: the flag, else `PPFD_PREFIX`, else the file.
    #[test]
    fn the_prefix_flag_wins_over_the_variable_and_the_variable_over_the_file() {
        let dir = std::env::temp_dir().join(format!("ppfd-cli-prefix-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("ppfd.toml");
        std::fs::write(&file, "prefix = \"from_file_\"\n").unwrap();
        let path = file.to_str().unwrap();
        let prefix = |args: &[&str], env: Option<&str>| {
            let mut all = vec!["ppfd", "--config", path];
            all.extend_from_slice(args);
            Args::parse_from(all)
                .config_with(env.map(str::to_owned))
                .unwrap()
                .prefix
        };
        assert_eq!(prefix(&[], None).as_deref(), Some("from_file_"));
        assert_eq!(prefix(&[], Some("from_env_")).as_deref(), Some("from_env_"));
        assert_eq!(
            prefix(&["--prefix", "from_flag_"], Some("from_env_")).as_deref(),
            Some("from_flag_")
        );
        let bad = Args::parse_from(["ppfd"]).config_with(Some("a/b".into()));
        let e = bad.unwrap_err().to_string();
        assert!(
            e.starts_with("PPFD_PREFIX: ") && e.contains("\"a/b\""),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn flags_override_the_file() {
        let dir = std::env::temp_dir().join(format!("ppfd-cli-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("ppfd.toml");
        std::fs::write(&file, "queue_capacity = 7\nmax_frame_age_ms = 50\n").unwrap();
        let args = Args::parse_from([
            "ppfd",
            "--config",
            file.to_str().unwrap(),
            "--max-frame-age-ms",
            "80",
        ]);
        let c = args.config().unwrap();
        assert_eq!(c.queue_capacity, 7);
        assert_eq!(c.max_frame_age_ms, 80);
        std::fs::write(
            &file,
            "[detector]\nvoting.reference_step = 3\nvoting.peaks_per_reference = 1\n",
        )
        .unwrap();
        let args = Args::parse_from([
            "ppfd",
            "--config",
            file.to_str().unwrap(),
            "--set",
            "voting.reference_step=5",
        ]);
        let p = args.config().unwrap().detect_params().unwrap();
        assert_eq!(p.voting.reference_step, 5);
        assert_eq!(p.voting.peaks_per_reference, 1);
        let args = Args::parse_from(["ppfd", "--set", "voting.reference_step"]);
        assert!(args
            .config()
            .unwrap_err()
            .to_string()
            .contains("stage.field=value"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
