//! End-to-end tests of how the daemon starts and stops: stop requests while it loads its models,
//! requests that come while it stops, and the signals that stop it. The daemon runs with the
//! transport-only engine, each test under its own iceoryx2 prefix.

use std::path::Path;
use std::time::{Duration, Instant};

use ppfd_client::{Client, ClientOptions, DetectOptions, Error, Status};
use ppfd_tests::{fake_model_dir, Prefix};

mod common;
use common::{camera, fake_daemon, spawn_fake_daemon, DAEMON, STARTUP};

fn connect(prefix: &Prefix) -> Client {
    let options = ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_secs(2),
        ..Default::default()
    };
    Client::connect_with(&options).expect("client connects")
}

/// A stop requested while the models load at start ends the daemon after the model being
/// loaded, without serving: a supervisor's SIGTERM is not kept waiting for every model.
/// Without the check between models, the daemon would load all five (5 s), say it is ready and
/// only then stop.
#[test]
fn a_stop_while_the_models_load_ends_the_daemon_before_it_serves() {
    let prefix = Prefix::new("stopload");
    let models = fake_model_dir("stopload", &[1, 2, 3, 4, 5]);
    let mut d = spawn_fake_daemon(
        &prefix,
        &models,
        &[],
        &[("PPFD_FAKE_LOAD_DELAY_MS", "1000")],
    );
    // Let the node come up and the first model start loading.
    std::thread::sleep(Duration::from_millis(1500));
    let asked = Instant::now();
    d.signal(libc::SIGTERM);
    let status = d
        .wait_exit(Duration::from_secs(10))
        .expect("the daemon stops");
    let took = asked.elapsed();
    assert!(status.success(), "{status:?}");
    assert!(
        took < Duration::from_millis(2500),
        "stopped {took:?} after the request; loading every model takes 5 s"
    );
    let mut out = String::new();
    use std::io::Read;
    d.stdout.take().unwrap().read_to_string(&mut out).unwrap();
    assert!(!out.contains("ppfd ready"), "it said it was ready: {out:?}");
}

/// While the daemon loads its models at start, statistics are answered at once and say how far
/// it is; the model list waits until every model is loaded, then lists them all. A monitor
/// asking whether the daemon is up gets its answer within its timeout (here 2 s, with 4 s of
/// loading to go).
#[test]
fn statistics_are_answered_while_the_models_load() {
    let prefix = Prefix::new("loadstats");
    let models = fake_model_dir("loadstats", &[1, 2, 3, 4, 5]);
    let mut d = spawn_fake_daemon(
        &prefix,
        &models,
        &[],
        &[("PPFD_FAKE_LOAD_DELAY_MS", "1000")],
    );
    // The node comes up at once; the first model takes a second.
    std::thread::sleep(Duration::from_millis(300));
    let client = connect(&prefix);
    let asked = Instant::now();
    let (stats, message) = client
        .statistics()
        .expect("statistics answered while the models load");
    assert!(
        asked.elapsed() < Duration::from_millis(1000),
        "answered after {:?}",
        asked.elapsed()
    );
    assert!(stats.models_loaded < 5, "{stats:?}");
    assert_eq!(stats.startup_files, 5, "{stats:?}");
    assert!(stats.startup_files_done < 5, "{stats:?}");
    assert_eq!(message, "detector: defaults");
    // Held until the folder is loaded: the list is whole.
    let options = ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_secs(20),
        ..Default::default()
    };
    let patient = Client::connect_with(&options).expect("client connects");
    let listed: Vec<u32> = patient
        .models()
        .expect("models listed once loaded")
        .iter()
        .map(|m| m.object_id)
        .collect();
    assert_eq!(listed, [1, 2, 3, 4, 5]);
    d.wait_line("ppfd ready", STARTUP);
    let stats = client.stats().unwrap();
    assert_eq!(stats.models_loaded, 5);
    assert_eq!(
        (
            stats.startup_files,
            stats.startup_files_done,
            stats.startup_files_failed
        ),
        (5, 5, 0)
    );
}

/// Clients that ask for the model list while the models load and leave before the answer are
/// let go of: each would keep its connection in iceoryx2's buffer of expired connections, which
/// panics beyond its size (128 here), so a monitor polling the list with a short timeout during
/// a long first start took the daemon down. After 200 such clients the daemon still answers.
/// Clients that die this fast outrun iceoryx2's removal of their connections: past 32 held, the
/// daemon lets go of one all the same, and a client on a reused channel may see its request
/// dropped (`Error::Dropped`, at once) rather than time out.
#[test]
fn clients_that_leave_while_the_models_load_are_let_go_of() {
    let prefix = Prefix::new("loadleave");
    let models = fake_model_dir("loadleave", &[1]);
    // Far longer than the clients take, on however loaded a machine.
    let mut d = spawn_fake_daemon(
        &prefix,
        &models,
        &[],
        &[("PPFD_FAKE_LOAD_DELAY_MS", "60000")],
    );
    std::thread::sleep(Duration::from_millis(300));
    let hasty = ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_millis(5),
        ..Default::default()
    };
    for _ in 0..200 {
        let client = Client::connect_with(&hasty).expect("client connects");
        match client.models() {
            Err(Error::Timeout(_) | Error::Dropped) => {}
            other => panic!("expected no answer while the models load, got {other:?}"),
        }
    }
    // Statistics are answered while the models load: the daemon is up and serving.
    let stats = connect(&prefix).stats().expect("the daemon answers");
    assert_eq!(
        (stats.startup_files, stats.startup_files_done),
        (1, 0),
        "{stats:?}"
    );
    assert_eq!(d.wait_exit(Duration::ZERO), None, "the daemon ended");
    // Stopping would wait for the model being loaded; dropping `d` kills the daemon.
}

/// Model loads run one at a time: while they do, the statistics say how many run and wait, so
/// that a load slow to answer can be told from a lost one; once they are done, both are 0.
#[test]
fn statistics_show_the_model_loads_running_and_waiting() {
    let prefix = Prefix::new("loadqueue");
    let models = fake_model_dir("loadqueue", &[1, 2, 3, 4]);
    let _d = fake_daemon(&prefix, &models, &[], &[("PPFD_FAKE_LOAD_DELAY_MS", "400")]);
    let options = ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_secs(20),
        ..Default::default()
    };
    let loads: Vec<_> = [2u32, 3, 4]
        .into_iter()
        .map(|id| {
            let (options, path) = (options.clone(), models.join(format!("obj_{id:06}.fake")));
            std::thread::spawn(move || {
                let client = Client::connect_with(&options).expect("client connects");
                client
                    .load_model(path.to_str().unwrap(), 0)
                    .map(|m| m.object_id)
            })
        })
        .collect();
    let client = connect(&prefix);
    let deadline = Instant::now() + Duration::from_secs(5);
    let seen = loop {
        let stats = client.stats().expect("statistics");
        // A load's file is checked (counted waiting) before it runs.
        if stats.model_loads_running > 0 {
            break stats;
        }
        assert!(Instant::now() < deadline, "no model load seen: {stats:?}");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(seen.model_loads_running, 1, "{seen:?}");
    assert!(seen.model_loads_waiting <= 2, "{seen:?}");
    let mut loaded: Vec<u32> = loads
        .into_iter()
        .map(|t| t.join().unwrap().expect("loaded"))
        .collect();
    loaded.sort();
    assert_eq!(loaded, [2, 3, 4]);
    let stats = client.stats().expect("statistics");
    assert_eq!(
        (stats.model_loads_running, stats.model_loads_waiting),
        (0, 0)
    );
}

/// A model file whose check does not end (a `stat` on a hung network mount) holds neither the
/// daemon's other requests nor its stop: the check runs on a thread of its own, the load
/// waits as a load waiting its turn, and the daemon stops on SIGTERM, answering it "shutting
/// down". With the check on the I/O thread, the statistics below would wait 60 s.
#[test]
fn a_model_file_whose_check_hangs_holds_nothing_else() {
    let prefix = Prefix::new("hungcheck");
    let models = fake_model_dir("hungcheck", &[1, 2]);
    let mut d = fake_daemon(
        &prefix,
        &models,
        &[],
        &[("PPFD_FAKE_PATH_CHECK_DELAY_MS", "60000")],
    );
    let options = ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_secs(2),
        ..Default::default()
    };
    let path = models.join("obj_000002.fake");
    let hung = {
        let options = options.clone();
        std::thread::spawn(move || {
            let client = Client::connect_with(&options).expect("client connects");
            client.load_model_within(path.to_str().unwrap(), 0, Duration::from_secs(30))
        })
    };
    let client = connect(&prefix);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let stats = client
            .stats()
            .expect("statistics answered beside the hung check");
        if stats.model_loads_waiting == 1 {
            assert_eq!(stats.model_loads_running, 0, "{stats:?}");
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the load never counted: {stats:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(client.models().expect("the model list").len(), 2);
    let asked = Instant::now();
    d.signal(libc::SIGTERM);
    let status = d.wait_exit(Duration::from_secs(10));
    assert!(status.is_some_and(|s| s.success()), "{status:?}");
    assert!(
        asked.elapsed() < Duration::from_secs(5),
        "{:?}",
        asked.elapsed()
    );
    match hung.join().unwrap() {
        Err(Error::Refused { status, .. }) => assert_eq!(status, Status::ShuttingDown),
        other => panic!("the hung load answered {other:?}"),
    }
}

/// A model load bounded by its own timeout: one longer than the client's control timeout waits
/// for a slow build, where the plain load times out (and is still carried out: its model is
/// served after).
#[test]
fn a_model_load_takes_a_timeout_of_its_own() {
    let prefix = Prefix::new("loadtimeout");
    let models = fake_model_dir("loadtimeout", &[1, 2, 3]);
    let _d = fake_daemon(&prefix, &models, &[], &[("PPFD_FAKE_LOAD_DELAY_MS", "800")]);
    let client = Client::connect_with(&ClientOptions {
        prefix: Some(prefix.0.clone()),
        control_timeout: Duration::from_millis(300),
        ..Default::default()
    })
    .expect("client connects");
    let path = |id: u32| models.join(format!("obj_{id:06}.fake"));
    let plain = client.load_model(path(2).to_str().unwrap(), 0);
    assert!(matches!(plain, Err(Error::Timeout(_))), "{plain:?}");
    // Waits behind the first load (one at a time), then its own.
    let bounded = client
        .load_model_within(path(3).to_str().unwrap(), 0, Duration::from_secs(20))
        .expect("loaded within its own timeout");
    assert_eq!(bounded.object_id, 3);
    let stats = client.stats().expect("statistics");
    assert_eq!(
        (stats.model_loads_running, stats.model_loads_waiting),
        (0, 0)
    );
}

/// While the daemon stops (here on SIGHUP, as when its terminal closes), a running detection
/// finishes and is answered, and what comes meanwhile is answered at once: statistics and the
/// model list as usual, detections and model loads "shutting down": no client waits out its
/// timeout for an answer that will not come, and SIGHUP does not cut the running detection off.
#[test]
fn requests_that_come_while_the_daemon_stops_are_answered() {
    let prefix = Prefix::new("stopping");
    let models = fake_model_dir("stopping", &[1]);
    let mut d = fake_daemon(&prefix, &models, &[], &[("PPFD_FAKE_DELAY_MS", "3000")]);
    let _cam = camera(&prefix, "cam0", &["--fps", "20"]);
    std::thread::sleep(Duration::from_millis(300));

    let running = {
        let prefix = prefix.0.clone();
        std::thread::spawn(move || {
            let client = Client::connect_with(&ClientOptions {
                prefix: Some(prefix),
                ..Default::default()
            })
            .expect("client connects");
            let opts = DetectOptions {
                timeout: Duration::from_secs(20),
                ..Default::default()
            };
            client.detect("cam0", &[1], &opts)
        })
    };
    std::thread::sleep(Duration::from_millis(500));
    d.signal(libc::SIGHUP);
    std::thread::sleep(Duration::from_millis(300));

    let client = connect(&prefix);
    let opts = DetectOptions {
        timeout: Duration::from_secs(2),
        ..Default::default()
    };
    let asked = Instant::now();
    match client.detect("cam0", &[1], &opts) {
        Err(Error::Refused { status, .. }) => assert_eq!(status, Status::ShuttingDown),
        other => panic!("a detection while stopping: {other:?}"),
    }
    assert!(
        asked.elapsed() < Duration::from_secs(1),
        "{:?}",
        asked.elapsed()
    );
    let stats = client.stats().expect("statistics while stopping");
    assert_eq!(stats.models_loaded, 1);
    match client.load_model("/nonexistent/x.fake", 0) {
        Err(Error::Refused { status, .. }) => assert_eq!(status, Status::ShuttingDown),
        other => panic!("a model load while stopping: {other:?}"),
    }

    let answer = running
        .join()
        .unwrap()
        .expect("the running detection is answered");
    assert_eq!(answer.hypotheses.len(), 1);
    let status = d
        .wait_exit(Duration::from_secs(10))
        .expect("the daemon stops");
    assert!(status.success(), "{status:?}");
}

/// A node of this test process under `prefix`, to hold services as other processes would.
fn node_under(prefix: &Prefix) -> iceoryx2::node::Node<iceoryx2::service::ipc::Service> {
    use iceoryx2::prelude::*;
    let mut config = iceoryx2::config::Config::default();
    config.global.prefix = FileName::new(prefix.0.as_bytes()).unwrap();
    NodeBuilder::new()
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .unwrap()
}

/// The stderr of a daemon started under `prefix` with the fake engine, which must refuse to
/// start (exit code 1).
fn refused_start(prefix: &Prefix, models: &Path) -> String {
    let out = std::process::Command::new(DAEMON)
        .args(["--prefix", &prefix.0, "--models", models.to_str().unwrap()])
        .env("PPFD_TEST_ENGINE", "fake")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    stderr
}

/// A daemon that meets `ppfd/detect` held open with the messages of another protocol version
/// (clients of another ppfd release still running under the prefix) says so and exits 1,
/// where it said only iceoryx2's type error.
#[test]
fn a_daemon_meeting_another_protocol_version_says_so() {
    use iceoryx2::prelude::*;
    use ppfd_client::protocol::detect::DetectResponseHeader;
    use ppfd_client::protocol::services;
    use ppfd_client::PoseHypothesis;

    /// A request header of another layout, under the same type name.
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("ppfd::DetectRequestHeader")]
    #[repr(C)]
    struct OtherRequestHeader {
        fields: [u64; 38],
    }

    let prefix = Prefix::new("otherversion");
    let models = fake_model_dir("otherversion", &[1]);
    let node = node_under(&prefix);
    let _held = node
        .service_builder(&ServiceName::new(services::DETECT).unwrap())
        .request_response::<[u16], [PoseHypothesis]>()
        .request_user_header::<OtherRequestHeader>()
        .response_user_header::<DetectResponseHeader>()
        .create()
        .unwrap();
    let stderr = refused_start(&prefix, &models);
    assert!(
        stderr.contains("cannot open ppfd/detect: processes of another ppfd release"),
        "{stderr}"
    );
}

/// A daemon started while two others are starting (both listening on `ppfd/daemon`, the most
/// it takes) is told that other daemons start or serve under its prefix.
#[test]
fn a_third_daemon_starting_at_once_is_told_others_start_or_serve() {
    use ppfd_client::protocol::services;

    let prefix = Prefix::new("thirddaemon");
    let models = fake_model_dir("thirddaemon", &[1]);
    let node = node_under(&prefix);
    let wake = services::daemon_wake_builder(&node)
        .open_or_create()
        .unwrap();
    let _listeners: Vec<_> = (0..services::limits::MAX_SERVERS)
        .map(|_| wake.listener_builder().create().unwrap())
        .collect();
    let stderr = refused_start(&prefix, &models);
    assert!(
        stderr.contains("other ppfd daemons are starting or serving with this prefix (2 listen")
            && stderr.contains("stop them first"),
        "{stderr}"
    );
}

/// The names of `dir`'s entries that start with `prefix`.
fn entries_of(dir: &Path, prefix: &str) -> Vec<String> {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(prefix))
        .collect()
}

/// A process killed between creating a shared memory segment and giving it its size leaves it
/// empty, and iceoryx2's cleanup of the dead process waits for it to get a size without end:
/// the housekeeping would stop for good (no cleanup, no camera discovery), and the daemon could
/// not stop, since it joins the thread. The killed camera's empty segments go once a second
/// old, the camera is cleaned up, and the daemon stops on SIGTERM. (Only root meets such
/// segments: their mode, 0200 while they are made, refuses other users, and iceoryx2 removes
/// them itself.)
#[test]
fn an_empty_segment_of_a_killed_process_does_not_stall_the_cleanup() {
    use std::os::unix::fs::PermissionsExt;
    let prefix = Prefix::new("emptyseg");
    let models = fake_model_dir("emptyseg", &[1]);
    let mut d = fake_daemon(&prefix, &models, &[], &[]);
    let config = iceoryx2::config::Config::default();
    let nodes = std::path::PathBuf::from(config.global.node_dir().to_string());
    let shm = Path::new(ppfd_client::protocol::services::SHARED_MEMORY_DIR);
    let folders_of_prefix = || -> Vec<std::path::PathBuf> {
        std::fs::read_dir(&nodes)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| !entries_of(p, &prefix.0).is_empty())
            .collect()
    };
    let before = folders_of_prefix();
    let mut cam = camera(&prefix, "cam0", &["--fps", "20"]);
    // The camera's node once its ports are made (a node a process makes for a moment is gone
    // by then), and one of its ports.
    std::thread::sleep(Duration::from_millis(300));
    let camera_folder = folders_of_prefix()
        .into_iter()
        .find(|f| !before.contains(f))
        .expect("the camera's node folder");
    let ports: Vec<String> = entries_of(&camera_folder, &prefix.0)
        .iter()
        .filter_map(|n| {
            n.strip_prefix(&prefix.0)?
                .strip_suffix(".port_tag")
                .map(str::to_owned)
        })
        .collect();
    assert!(!ports.is_empty(), "no port tag of the camera");
    // A connection of each of its ports left empty, named as iceoryx2 0.10 names connections:
    // the cleanup of the camera opens every connection that names one of its ports.
    let hash = "b9fc73e5c1f646968758453273c6c65cb372831b";
    let empty: Vec<std::path::PathBuf> = ports
        .iter()
        .map(|port| {
            let path = shm.join(format!("{}{hash}_{port}_4242.connection", prefix.0));
            std::fs::File::create(&path).unwrap();
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o200)).unwrap();
            path
        })
        .collect();

    cam.signal(libc::SIGKILL);
    cam.wait_exit(Duration::from_secs(5))
        .expect("the camera ends");
    let until = Instant::now() + Duration::from_secs(10);
    while camera_folder.exists() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        !camera_folder.exists(),
        "the killed camera is not cleaned up"
    );
    assert!(empty.iter().all(|p| !p.exists()), "an empty segment stays");
    d.signal(libc::SIGTERM);
    assert!(
        d.wait_exit(Duration::from_secs(10)).is_some(),
        "the daemon does not stop"
    );
}
