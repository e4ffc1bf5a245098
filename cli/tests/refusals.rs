//! Refusals of a running daemon (`ppf serve`, the real detector) as its client sees them: a
//! message reaches the client whole, with the end that says how to fix the input.

mod common;

use common::{Scratch, ServedPart};
use ppfd_client::{
    monotonic_now_ns, Client, ClientOptions, DetectOptions, Error, FrameHeader, Intrinsics, Status,
};
use ppfd_models::synthetic::parts::Part;

/// A client of `served`'s daemon that can send its scene's frame inline.
fn client(served: &ServedPart) -> Client {
    Client::connect_with(&ClientOptions {
        prefix: Some(served.prefix.clone()),
        inline_frame_capacity: served.scene.frame.depth.len(),
        ..Default::default()
    })
    .expect("connected")
}

/// The header of `served`'s scene frame, stamped now.
fn header(served: &ServedPart) -> FrameHeader {
    let f = &served.scene.frame;
    let k = f.intrinsics;
    FrameHeader {
        width: f.width,
        height: f.height,
        intrinsics: Intrinsics {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
        },
        depth_scale_mm: f.depth_scale_mm,
        capture_time_ns: monotonic_now_ns(),
        ..Default::default()
    }
}

fn detect(served: &ServedPart, client: &Client, frame: &FrameHeader) -> ppfd_client::Result<()> {
    let objects = [served.part.object_id()];
    client
        .detect_inline(
            frame,
            &served.scene.frame.depth,
            &objects,
            &DetectOptions::default(),
        )
        .map(drop)
}

/// Millimetres declared as hundredths of a millimetre: the refusal names the working range,
/// the values and, at its end, the scale that would fit them.
#[test]
fn a_frame_in_another_unit_is_refused_with_the_scale_that_fits() {
    let scratch = Scratch::new("refusal-scale");
    let served = ServedPart::start(&scratch, "refusal_scale", Part::TPipe, 5);
    let client = client(&served);
    let mut frame = header(&served);
    assert!(
        detect(&served, &client, &frame).is_ok(),
        "the frame as it is"
    );
    frame.depth_scale_mm /= 100.0;
    match detect(&served, &client, &frame) {
        Err(Error::Refused {
            status: Status::InvalidFrame,
            message,
            ..
        }) => {
            assert!(
                message.contains("working range")
                    && message.ends_with("is the frame's depth_scale_mm right?"),
                "{message}"
            );
        }
        other => panic!("{other:?}"),
    }
}

/// A driver that publishes frames whose header names another camera (a copied header, a
/// driver started with the wrong name) has them refused, both cameras named: poses in another
/// camera's frame of reference would send a robot to the wrong place.
#[test]
fn a_frame_naming_another_camera_is_refused() {
    let scratch = Scratch::new("refusal-name");
    let served = ServedPart::start(&scratch, "refusal_name", Part::TPipe, 5);
    let client = client(&served);
    let f = &served.scene.frame;
    let k = header(&served).intrinsics;
    let mut other = ppfd_client::CameraPublisher::new(
        Some(&served.prefix),
        "left",
        2,
        f.width,
        f.height,
        k,
        f.depth_scale_mm,
    )
    .unwrap();
    let objects = [served.part.object_id()];
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    let refused = loop {
        let mut frame = other.loan().unwrap().write_from_slice(&f.depth).unwrap();
        frame.header_mut().camera_name =
            ppfd_client::protocol::text::encode_name("camera", "right").unwrap();
        frame.send(monotonic_now_ns()).unwrap();
        match client.detect("left", &objects, &DetectOptions::default()) {
            Err(Error::Refused {
                status: Status::NoFrame | Status::UnknownCamera,
                ..
            }) if std::time::Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(50))
            }
            other => break other,
        }
    };
    match refused {
        Err(Error::Refused {
            status: Status::InvalidFrame,
            message,
            ..
        }) => assert!(
            message.contains("camera \"left\"") && message.contains("named camera \"right\""),
            "{message}"
        ),
        other => panic!("{other:?}"),
    }
}
