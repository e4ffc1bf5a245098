//! A camera driver, a viewer and a client given no prefix take `PPFD_PREFIX`, as the daemon
//! does: a driver written as the README shows publishes where the daemon started in the same
//! environment looks. The only test of its binary, since it sets the process's environment.

use ppfd_client::{CameraPublisher, CameraViewer, Intrinsics};

#[test]
fn no_prefix_is_the_one_in_ppfd_prefix() {
    let prefix = format!("cenv{}_", std::process::id());
    std::env::set_var("PPFD_PREFIX", &prefix);
    let publisher = CameraPublisher::new(None, "envcam", 1, 640, 480, Intrinsics::LMO, 1.0)
        .expect("a publisher");
    // Found under the variable's prefix, named explicitly; not under another.
    let viewer = CameraViewer::open(Some(&prefix), "envcam");
    assert!(viewer.is_ok(), "{:?}", viewer.err());
    let elsewhere = format!("cenv{}_other_", std::process::id());
    assert!(CameraViewer::open(Some(&elsewhere), "envcam").is_err());
    // And a viewer given no prefix finds it too.
    assert!(CameraViewer::open(None, "envcam").is_ok());
    drop((publisher, viewer));
    // A value the daemon would refuse is refused by name, by a driver and a client alike.
    std::env::set_var("PPFD_PREFIX", "cell1");
    let refused = CameraPublisher::new(None, "envcam", 1, 640, 480, Intrinsics::LMO, 1.0)
        .err()
        .expect("refused");
    let text = refused.to_string();
    assert!(
        text.contains("PPFD_PREFIX: prefix name \"cell1\" must end with '_'"),
        "{text}"
    );
    let refused = ppfd_client::Client::connect_with(&Default::default())
        .err()
        .expect("refused");
    let text = refused.to_string();
    assert!(
        text.contains("PPFD_PREFIX: prefix name \"cell1\""),
        "{text}"
    );
    std::env::remove_var("PPFD_PREFIX");
    ppfd_client::remove_prefix_leftovers(&prefix).unwrap();
    ppfd_client::remove_prefix_leftovers(&elsewhere).unwrap();
}
