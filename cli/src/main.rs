//! `ppf`: the ppfd command line.

mod bench;
mod common;
mod daemon;
mod demo;
mod detect;
mod detect_offline;
mod eval;
mod generate;
mod model;
mod offline;
mod overlay;
mod profile;
mod replay;
mod requirements;
mod score;
mod stop;

use clap::{CommandFactory, Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "ppf",
    version,
    about = "ppfd command line: models, detection, evaluation"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Build and inspect object model files.
    #[command(subcommand)]
    Model(model::ModelCommand),
    /// Time the detector's stages on a dataset frame, per object (medians of repeated runs).
    Profile(profile::ProfileArgs),
    /// Publish the depth frames of a BOP dataset as a camera.
    Replay(replay::ReplayArgs),
    /// Detect objects: in a camera's newest frame through the daemon (`--camera`), or in a
    /// frame of a BOP dataset in this process (`--dataset --scene --image`).
    Detect(detect_offline::DetectCommand),
    /// Profile the daemon's latency with many requests from several clients.
    Bench(bench::BenchArgs),
    /// List, load or drop the daemon's models.
    Models(daemon::ModelsArgs),
    /// Print the daemon's statistics.
    Stats(daemon::StatsArgs),
    /// Start a daemon, publish a generated scene, detect, compare with the truth, stop.
    Demo(demo::DemoArgs),
    /// Write the generated scene `demo` shows as a BOP dataset: the parts' meshes (or a
    /// folder's own, `--models`), the depth image, its camera and ground truth.
    Generate(generate::GenerateArgs),
    /// Run the ppfd daemon in this process, with ppfd's flags (what `ppf demo` starts);
    /// `ppf serve --help` prints ppfd's help.
    #[command(hide = true, disable_help_flag = true)]
    Serve {
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Detect in every image of a BOP dataset, write the BOP results CSV and score it.
    Eval(eval::EvalArgs),
    /// Score a BOP results CSV against a dataset (BOP 2018 recall, BOP 2019 AR).
    Score(score::ScoreArgs),
}

/// Parses the command line as clap does, with the checks clap cannot express: `ppf detect`
/// without either of its modes is a usage error naming both.
fn parse_cli<I, T>(args: I) -> Result<Cli, clap::Error>
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let cli = Cli::try_parse_from(args)?;
    if let Command::Demo(demo) = &cli.command {
        if let Some(e) = demo.flag_without_its_scene() {
            let mut command = Cli::command();
            command.build();
            let demo = command
                .find_subcommand_mut("demo")
                .expect("demo is a subcommand");
            return Err(demo.error(clap::error::ErrorKind::ArgumentConflict, e));
        }
    }
    if let Command::Detect(detect) = &cli.command {
        if !detect.has_mode() {
            let mut command = Cli::command();
            command.build();
            let detect = command
                .find_subcommand_mut("detect")
                .expect("detect is a subcommand");
            return Err(detect.error(
                clap::error::ErrorKind::MissingRequiredArgument,
                detect_offline::NO_MODE,
            ));
        }
    }
    Ok(cli)
}

fn main() {
    let cli = parse_cli(std::env::args_os()).unwrap_or_else(|e| e.exit());
    if let Command::Serve { args } = &cli.command {
        let argv = std::iter::once("ppfd".to_owned()).chain(args.iter().cloned());
        let engine = Box::new(|config: &ppfd::config::DaemonConfig| {
            let engine = ppfd::ppf_engine::PpfEngine::from_config(config)?;
            Ok(std::sync::Arc::new(engine) as std::sync::Arc<dyn ppfd::DetectionEngine>)
        });
        // ppfd's exit codes, as `ppfd` has them: 2 for a bad configuration (a bad `--set`).
        std::process::exit(match ppfd::cli::main_with_args(argv, engine) {
            code if code == std::process::ExitCode::SUCCESS => 0,
            code if code == std::process::ExitCode::from(2) => 2,
            _ => 1,
        });
    }
    // Like other command-line tools, end quietly when the reader of the output goes away
    // (`ppf model info … | head -1`) instead of failing on the next print. Not for `serve`
    // above: a daemon outlives whoever read its first line.
    // SAFETY: sets the default disposition of one signal before any thread is started.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    let result = match cli.command {
        Command::Model(cmd) => model::run(cmd),
        Command::Profile(args) => profile::run(args),
        Command::Replay(args) => {
            connect_or_exit(&args.connect);
            replay::run(args).map_err(Into::into)
        }
        Command::Detect(args) => match args.into_target() {
            Ok(detect_offline::DetectTarget::Camera(a)) => {
                connect_or_exit(&a.connect);
                detect::run(a).map_err(Into::into)
            }
            Ok(detect_offline::DetectTarget::Dataset(a)) => detect_offline::run(a),
            Err(e) => usage_error(&e),
        },
        Command::Bench(args) => match args.check() {
            Ok(()) => bench::run(args).map_err(Into::into),
            Err(e) => usage_error(&e),
        },
        Command::Models(args) => {
            connect_or_exit(&args.connect);
            daemon::models(args).map_err(Into::into)
        }
        Command::Stats(args) => {
            connect_or_exit(&args.connect);
            daemon::stats(args).map_err(Into::into)
        }
        // The request options are checked before the scene is drawn and the daemon started.
        Command::Demo(args) => match args.requirements.wire() {
            Ok(_) => demo::run(args).map_err(Into::into),
            Err(e) => usage_error(&e),
        },
        Command::Generate(args) => generate::run(args).map_err(Into::into),
        Command::Serve { .. } => unreachable!("handled above"),
        Command::Score(args) => score::run(args),
        Command::Eval(args) => eval::run(args),
    };
    if let Some(signal) = stop::stop_signal() {
        // What the command held is let go; the error it ended with is the signal's doing.
        eprintln!("stopped by {}", stop::signal_name(signal));
        std::process::exit(128 + signal);
    }
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

/// Ends with a usage error when the daemon's prefix is one it would refuse: `--prefix` is
/// checked by clap, `PPFD_PREFIX` here (a command that reaches no daemon does not read it).
fn connect_or_exit(connect: &common::Connect) {
    if let Err(e) = connect.prefix() {
        usage_error(&e);
    }
}

/// Ends with a usage error's code, 2, as clap's own errors do.
fn usage_error(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(2);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serve_passes_help_on_to_the_daemon() {
        let cli = Cli::try_parse_from(["ppf", "serve", "--help"]).unwrap();
        match cli.command {
            Command::Serve { args } => assert_eq!(args, ["--help"]),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn daemon_subcommands_parse() {
        let cli =
            Cli::try_parse_from(["ppf", "detect", "--camera", "k", "--objects", "1,5,6"]).unwrap();
        match cli.command {
            Command::Detect(a) => assert_eq!(a.objects, vec![1, 5, 6]),
            other => panic!("{other:?}"),
        }
        let cli = Cli::try_parse_from([
            "ppf",
            "bench",
            "--camera",
            "k",
            "--objects",
            "2",
            "--clients",
            "3",
        ])
        .unwrap();
        assert!(
            matches!(cli.command, Command::Bench(ref a) if a.clients == 3 && a.objects == vec![bench::Objects(vec![2])])
        );
        // One list per client, in turn.
        let cli = Cli::try_parse_from([
            "ppf",
            "bench",
            "--camera",
            "k",
            "--objects",
            "1,5",
            "--objects",
            "8,9,10",
        ])
        .unwrap();
        match cli.command {
            Command::Bench(a) => assert_eq!(
                a.objects,
                vec![bench::Objects(vec![1, 5]), bench::Objects(vec![8, 9, 10])]
            ),
            other => panic!("{other:?}"),
        }
        for args in [
            vec!["ppf", "replay", "/d", "--camera", "k", "--loop"],
            vec!["ppf", "models", "--drop", "3"],
            vec!["ppf", "stats", "--json"],
            vec!["ppf", "demo"],
        ] {
            Cli::try_parse_from(&args).unwrap_or_else(|e| panic!("{args:?}: {e}"));
        }
    }

    /// The request options' flags become the request's requirements, and a value out of
    /// range is refused with its name and range before anything is sent; `--camera
    /// --overlay` needs the models folder to draw from.
    #[test]
    fn detect_takes_the_request_options_and_refuses_them_out_of_range() {
        use ppfd_client::{order, Requirements};
        let target = |extra: &[&str]| -> Result<Requirements, String> {
            let args = ["ppf", "detect", "--camera", "k", "--objects", "8"];
            let args: Vec<&str> = args.iter().chain(extra).copied().collect();
            let cli = Cli::try_parse_from(args).map_err(|e| e.to_string())?;
            match cli.command {
                Command::Detect(a) => match a.into_target()? {
                    detect_offline::DetectTarget::Camera(c) => Ok(c.requirements),
                    _ => panic!("a camera request"),
                },
                other => panic!("{other:?}"),
            }
        };
        assert_eq!(target(&[]).unwrap(), Requirements::default());
        let r = target(&[
            "--min-score",
            "0.3",
            "--instance-distance",
            "0.5",
            "--roi",
            "10,20,300,200",
            "--max-tilt",
            "30",
            "--tilt-axis",
            "-1,0,0",
            "--order",
            "distance",
        ])
        .unwrap();
        assert_eq!(r.min_score, 0.3);
        assert_eq!(r.instance_distance_fraction, 0.5);
        assert_eq!((r.region_of_interest.x, r.region_of_interest.y), (10, 20));
        assert_eq!(
            (r.region_of_interest.width, r.region_of_interest.height),
            (300, 200)
        );
        assert_eq!(r.pose_restriction.max_angle_deg, 30.0);
        assert_eq!(r.pose_restriction.model_axis, [-1.0, 0.0, 0.0]);
        assert_eq!(r.pose_restriction.camera_direction, [0.0, 0.0, -1.0]);
        assert_eq!(r.order, order::DISTANCE);
        // 0 is the daemon's distance, as the protocol's range message and Python offer it.
        let r = target(&["--instance-distance", "0"]).unwrap();
        assert_eq!(r.instance_distance_fraction, 0.0);
        for (extra, expected) in [
            (&["--min-score", "2"][..], "minimum score 2 is out of range"),
            (
                &["--instance-distance", "3"],
                "or 0 for the daemon's setting",
            ),
            (&["--max-tilt", "200"], "200 degrees is out of range"),
            (&["--roi", "5,5,0,10"], "region of interest 0x10"),
            (
                &["--max-tilt", "10", "--tilt-direction", "0,0,0"],
                "camera direction",
            ),
            (&["--overlay", "o.png"], "--models DIR"),
            (&["--roi", "5,5,10"], "--roi takes 4 numbers"),
            (
                &["--max-tilt", "10", "--tilt-axis", "1,0"],
                "--tilt-axis takes 3 numbers",
            ),
        ] {
            let e = target(extra).unwrap_err();
            assert!(e.contains(expected), "{extra:?}: {e}");
        }
        let e = Cli::try_parse_from([
            "ppf",
            "detect",
            "--dataset",
            "/d",
            "--scene",
            "2",
            "--image",
            "3",
            "--diagnose",
            "--min-score",
            "0.2",
        ])
        .map_err(|e| e.to_string())
        .and_then(|cli| match cli.command {
            Command::Detect(a) => a.into_target().map(|_| ()),
            other => panic!("{other:?}"),
        })
        .unwrap_err();
        assert!(e.contains("--diagnose"), "{e}");
    }

    /// `--peaks` and `--reference-step` keep the ranges of the `--set` keys they name: a value
    /// out of range is refused, not clamped where it is used.
    #[test]
    fn the_voting_flags_take_the_ranges_of_their_keys() {
        let params = |extra: &[&str]| {
            let base = [
                "ppf",
                "detect",
                "--dataset",
                "/d",
                "--scene",
                "2",
                "--image",
                "3",
            ];
            let args: Vec<&str> = base.iter().chain(extra).copied().collect();
            match Cli::try_parse_from(args).unwrap().command {
                Command::Detect(a) => match a.into_target().unwrap() {
                    detect_offline::DetectTarget::Dataset(d) => d.params(),
                    _ => panic!("not the dataset mode"),
                },
                other => panic!("{other:?}"),
            }
        };
        assert_eq!(
            params(&["--peaks", "3"])
                .unwrap()
                .voting
                .peaks_per_reference,
            3
        );
        for (flag, value, range) in [
            ("--peaks", "0", "1..=32"),
            ("--peaks", "33", "1..=32"),
            ("--reference-step", "0", "1..=1000"),
        ] {
            let e = params(&[flag, value]).unwrap_err();
            assert!(e.contains(range), "{flag} {value}: {e}");
        }
    }

    /// A flag of the other mode is refused with its name, not dropped.
    #[test]
    fn detect_refuses_the_flags_of_the_other_mode() {
        let target = |args: &[&str]| {
            let cli = Cli::try_parse_from(args).map_err(|e| e.to_string())?;
            match cli.command {
                Command::Detect(a) => a.into_target().map(|_| ()),
                other => panic!("{other:?}"),
            }
        };
        let camera = ["ppf", "detect", "--camera", "k", "--objects", "8"];
        assert!(target(&camera).is_ok());
        for extra in [
            &["--set", "voting.reference_step=2"][..],
            &["--diagnose"],
            &["--peaks", "3"],
            &["--reference-step", "4"],
            &["--scene", "2"],
        ] {
            let args: Vec<&str> = camera.iter().chain(extra).copied().collect();
            let e = target(&args).unwrap_err();
            assert!(e.contains(extra[0]) && e.contains("--dataset"), "{e}");
        }
        let dataset = [
            "ppf",
            "detect",
            "--dataset",
            "/d",
            "--scene",
            "2",
            "--image",
            "3",
        ];
        assert!(target(&dataset).is_ok());
        let args: Vec<&str> = dataset.iter().copied().chain(["--prefix", "p_"]).collect();
        assert!(target(&args).unwrap_err().contains("without a daemon"));
        for extra in [&["--json"][..], &["--timeout-ms", "100"]] {
            let args: Vec<&str> = dataset.iter().chain(extra).copied().collect();
            let e = target(&args).unwrap_err();
            assert!(e.contains("cannot be used with"), "{e}");
        }
        for args in [&dataset[..], &camera] {
            let args: Vec<&str> = args.iter().copied().chain(["--objects", "5,6,5"]).collect();
            assert!(target(&args).unwrap_err().contains("object 5 twice"));
        }
        // The daemon's limit holds offline too.
        for n in ["0", "17"] {
            let args: Vec<&str> = dataset.iter().copied().chain(["--hypotheses", n]).collect();
            assert!(target(&args).unwrap_err().contains("1..=16"));
        }
    }

    /// Without `--camera` or `--dataset`, a usage error that names both modes (not clap's
    /// "required: --camera", which hides the offline one).
    #[test]
    fn detect_without_a_mode_names_both() {
        for args in [
            &["ppf", "detect"][..],
            &["ppf", "detect", "--objects", "1,5"],
        ] {
            let e = parse_cli(args).unwrap_err();
            assert_eq!(e.kind(), clap::error::ErrorKind::MissingRequiredArgument);
            let text = e.to_string();
            assert!(
                text.contains("--camera NAME")
                    && text.contains("--dataset DIR --scene N --image N"),
                "{text}"
            );
            assert!(text.contains("Usage: ppf detect"), "{text}");
        }
        parse_cli(["ppf", "detect", "--camera", "k", "--objects", "1"]).unwrap();
    }

    /// The demo refuses a count the daemon would refuse before it starts one, as detect does.
    #[test]
    fn demo_hypotheses_are_checked_when_parsed() {
        for n in ["0", "17", "20"] {
            let e = parse_cli(["ppf", "demo", "--hypotheses", n]).unwrap_err();
            assert!(e.to_string().contains("1..=16"), "{e}");
        }
        let cli = parse_cli(["ppf", "demo", "--hypotheses", "16"]).unwrap();
        assert!(matches!(cli.command, Command::Demo(ref a) if a.hypotheses == 16));
    }

    /// `--image` picks a dataset's frame, `--seed` and `--no-noise` shape the generated scene:
    /// each given for the other kind of scene is a usage error that says so, rather than
    /// ignored.
    #[test]
    fn demo_refuses_flags_of_the_other_scene() {
        for (args, named) in [
            (&["ppf", "demo", "--image", "2", "3"][..], "--dataset DIR"),
            (&["ppf", "demo", "--dataset", "/d", "--seed", "4"], "--seed"),
            (
                &["ppf", "demo", "--dataset", "/d", "--no-noise"],
                "--no-noise",
            ),
        ] {
            let e = parse_cli(args).unwrap_err();
            assert_eq!(e.kind(), clap::error::ErrorKind::ArgumentConflict);
            assert_eq!(e.exit_code(), 2);
            let text = e.to_string();
            assert!(
                text.contains(named) && text.contains("Usage: ppf demo"),
                "{text}"
            );
        }
        for args in [
            &["ppf", "demo", "--seed", "4", "--no-noise"][..],
            &["ppf", "demo", "--dataset", "/d", "--image", "2", "3"],
        ] {
            parse_cli(args).unwrap_or_else(|e| panic!("{args:?}: {e}"));
        }
    }

    #[test]
    fn rates_and_counts_that_cannot_work_are_refused() {
        for args in [
            &["ppf", "replay", "/d", "--camera", "k", "--fps", "0"][..],
            &["ppf", "replay", "/d", "--camera", "k", "--fps", "NaN"],
            &[
                "ppf",
                "profile",
                "--dataset",
                "/d",
                "--scene",
                "1",
                "--image",
                "1",
                "--repeat",
                "0",
            ],
        ] {
            assert!(Cli::try_parse_from(args).is_err(), "{args:?}");
        }
        let ok = ["ppf", "replay", "/d", "--camera", "k", "--fps", "0.5"];
        Cli::try_parse_from(ok).unwrap();
    }

    /// An object id of 0 is a usage error that says ids start at 1, in every command that takes
    /// `--objects`.
    #[test]
    fn object_id_zero_is_a_usage_error() {
        for args in [
            &["ppf", "eval", "/d", "--objects", "1,0"][..],
            &[
                "ppf",
                "detect",
                "--dataset",
                "/d",
                "--scene",
                "1",
                "--image",
                "1",
                "--objects",
                "0",
            ],
            &["ppf", "detect", "--camera", "k", "--objects", "0"],
            &[
                "ppf",
                "profile",
                "--dataset",
                "/d",
                "--scene",
                "1",
                "--image",
                "1",
                "--objects",
                "0",
            ],
            &["ppf", "generate", "/o", "--models", "/m", "--objects", "0"],
            &["ppf", "bench", "--camera", "k", "--objects", "5,0"],
        ] {
            let e = parse_cli(args).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{args:?}");
            assert!(
                e.to_string().contains("object ids start at 1"),
                "{args:?}: {e}"
            );
        }
        assert!(parse_cli(["ppf", "eval", "/d", "--objects", "1,5"]).is_ok());
    }

    /// Bench counts of zero and a prefix the daemon would not take are usage errors (exit code
    /// 2), named before any connection is tried; so are fewer requests than clients.
    #[test]
    fn bench_counts_and_prefixes_that_cannot_work_are_usage_errors() {
        let bench = |extra: &[&str]| {
            let mut args = vec!["ppf", "bench", "--camera", "k", "--objects", "1"];
            args.extend_from_slice(extra);
            parse_cli(args)
        };
        for (extra, said) in [
            (&["--requests", "0"][..], "must be at least 1"),
            (&["--clients", "0"], "must be at least 1"),
            (&["--prefix", "cell1"], "must end with '_'"),
        ] {
            let e = bench(extra).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{extra:?}");
            assert!(e.to_string().contains(said), "{extra:?}: {e}");
        }
        let e = parse_cli(["ppf", "stats", "--prefix", "a b_"]).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let Command::Bench(args) = bench(&["--requests", "1", "--clients", "3"])
            .unwrap()
            .command
        else {
            panic!("not bench");
        };
        assert!(args.check().unwrap_err().contains("fewer than --clients 3"));
        let Command::Bench(args) = bench(&["--requests", "3", "--clients", "3", "--prefix", "c_"])
            .unwrap()
            .command
        else {
            panic!("not bench");
        };
        assert!(args.check().is_ok());
    }

    #[test]
    fn camera_answers_show_checks_as_the_dataset_table_does() {
        use ppfd_client::protocol::detect::checks;
        assert_eq!(common::checks_letters(0), "");
        assert_eq!(
            common::checks_letters(
                checks::RESCORED | checks::REFINED | checks::CONSISTENT | checks::SILHOUETTE
            ),
            "RICS"
        );
        assert_eq!(
            common::checks_letters(checks::RESCORED | checks::SILHOUETTE),
            "RS"
        );
        assert_eq!(
            common::checks_letters(checks::RESCORED | checks::SILHOUETTE | checks::HINT),
            "RSH"
        );
        // The offline table passes the detector's bits straight in, as the daemon sends them.
        use ppfd_models::detect::detector::Checks;
        assert_eq!(
            [
                Checks::RESCORED,
                Checks::REFINED,
                Checks::CONSISTENT,
                Checks::SILHOUETTE,
                Checks::HINT
            ],
            [
                checks::RESCORED,
                checks::REFINED,
                checks::CONSISTENT,
                checks::SILHOUETTE,
                checks::HINT
            ]
        );
    }
}
