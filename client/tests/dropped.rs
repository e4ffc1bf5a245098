//! A request the daemon lets go of without an answer ends at once with `Error::Dropped`, not at
//! its timeout: the daemon does so with a dead client's request once more than 32 are held
//! (`MAX_ABANDONED_HELD`), and the channel it closes may be a new client's.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use ppfd_client::{Client, ClientOptions, DetectOptions, Error};
use ppfd_protocol::services;

/// A stand-in daemon on `prefix`: serves `ppfd/detect`, takes one request and drops it
/// unanswered. Says `ready` once it serves, then `dropped`.
fn server_that_drops_one_request(prefix: String, say: mpsc::Sender<&'static str>) {
    let mut config = iceoryx2::config::Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
    // Named as the daemon's node is: a client takes a prefix without one for a dead daemon.
    let node = NodeBuilder::new()
        .name(&NodeName::new(services::DAEMON_NODE).unwrap())
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .unwrap();
    let service = services::detect_builder(&node).open_or_create().unwrap();
    let server = service.server_builder().create().unwrap();
    say.send("ready").unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline {
        if let Some(active) = server.receive().unwrap() {
            drop(active);
            say.send("dropped").unwrap();
            // Keep serving (the client must not see "no daemon").
            std::thread::sleep(Duration::from_secs(2));
            return;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn a_request_let_go_of_without_an_answer_fails_at_once() {
    let prefix = format!("cdrop{}_", std::process::id());
    let (say, heard) = mpsc::channel();
    let server = {
        let prefix = prefix.clone();
        std::thread::spawn(move || server_that_drops_one_request(prefix, say))
    };
    assert_eq!(heard.recv_timeout(Duration::from_secs(20)), Ok("ready"));
    let client = Client::connect_with(&ClientOptions {
        prefix: Some(prefix.clone()),
        ..Default::default()
    })
    .unwrap();
    let started = Instant::now();
    let answer = client.detect(
        "cam0",
        &[1],
        &DetectOptions {
            timeout: Duration::from_secs(10),
            ..Default::default()
        },
    );
    let waited = started.elapsed();
    assert!(matches!(answer, Err(Error::Dropped)), "{answer:?}");
    assert_eq!(heard.recv_timeout(Duration::from_secs(1)), Ok("dropped"));
    assert!(waited < Duration::from_secs(5), "waited {waited:?}");
    server.join().unwrap();
    drop(client);
    ppfd_client::remove_prefix_leftovers(&prefix).unwrap();
}
