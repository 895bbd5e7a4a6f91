//! Sequences as a user renders them: `sylva submit` with a sun sweep and a
//! camera path against a real coordinator and two real worker processes
//! over loopback gRPC; the frames, their sheet and preview; the LB solved
//! once per sun on the farm and reused by a second pass; bad sequences
//! refused at the door.

use crate::common;

use common::{coordinator, scratch, small_scene, spawn, spec, submission, sylva, wait_for_workers};
use sylva_proto::pb;
use tonic::Code;

fn ok(args: &[&str]) -> String {
    let out = sylva(args, &[]);
    assert!(
        out.status.success(),
        "sylva {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// LB solves a worker has done, from its own status.
async fn lb_solves(addr: &str) -> u64 {
    let mut w = pb::worker_client::WorkerClient::connect(format!("http://{addr}")).await.unwrap();
    w.status(pb::StatusRequest {}).await.unwrap().into_inner().lb_solves
}

/// Linear RGB of an EXR file.
fn exr(path: &std::path::Path) -> Vec<f32> {
    image::open(path).unwrap().to_rgb32f().into_raw()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sun_sweep_along_a_camera_path_renders_on_the_farm_with_the_lb_solved_once_per_sun() {
    let dir = scratch("sequence");
    let scene = small_scene(&dir);
    let (w1, w2) = (
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
        spawn(&["worker", "--listen", "127.0.0.1:0"], &[]),
    );
    let workers = format!("{},{}", w1.addr, w2.addr);
    let coord = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &workers], &[]);
    let addr = coord.addr.clone();
    let mut c = coordinator(&addr, None).await;
    wait_for_workers(&mut c, 2).await;

    // The camera starts where the scene's does and swings round; the sun
    // starts at the scene's place (50°, 120°) and sinks westward.
    let path = dir.join("path.json");
    std::fs::write(
        &path,
        r#"[ { "frame": 0, "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
             { "frame": 3, "position": [-20, 9, -14], "look_at": [4, 6, 2], "fov_y_deg": 50 } ]"#,
    )
    .unwrap();
    let out = dir.join("shot.png");
    let frame_flags = ["--width", "64", "--height", "32", "--lighting", "lb"];
    let sequence_flags = [
        "--frames",
        "4",
        "--sun-from",
        "50,120",
        "--sun-to",
        "15,200",
        "--camera-path",
        path.to_str().unwrap(),
    ];
    let mut args = vec![
        "submit",
        scene.to_str().unwrap(),
        "--coordinator",
        &addr,
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(frame_flags);
    args.extend(sequence_flags);
    let said = ok(&args);
    let id = said.split_whitespace().next().unwrap().to_string();
    assert!(said.contains("4 frames"), "{said}");

    // Numbered frames, a contact sheet and an animated preview.
    for i in 0..4 {
        let f = image::open(dir.join(format!("shot-{i:04}.png"))).unwrap();
        assert_eq!((f.width(), f.height()), (64, 32));
    }
    assert!(!dir.join("shot-0004.png").exists());
    assert!(image::open(dir.join("shot-contact.png")).unwrap().width() > 2 * 64);
    let anim = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(dir.join("shot-preview.png")).unwrap(),
    ))
    .read_info()
    .unwrap();
    assert_eq!(anim.info().animation_control().map(|a| a.num_frames), Some(4));

    // The same sequence in one process (issue 39: sequences everywhere):
    // every frame byte for byte the farm's.
    let here = dir.join("here.png");
    let mut args = vec!["render", scene.to_str().unwrap(), "--local-workers", "0"];
    args.extend(["-o", here.to_str().unwrap()]);
    args.extend(frame_flags);
    args.extend(sequence_flags);
    let said = sylva(&args, &[]);
    let told = String::from_utf8_lossy(&said.stderr);
    assert!(said.status.success(), "{told}");
    let printed = String::from_utf8_lossy(&said.stdout);
    assert!(printed.contains("4 frames in this process"), "{printed}");
    for i in 0..4 {
        let (a, b) = (format!("here-{i:04}.png"), format!("shot-{i:04}.png"));
        assert!(
            std::fs::read(dir.join(&a)).unwrap() == std::fs::read(dir.join(&b)).unwrap(),
            "{a} differs from the farm's {b}"
        );
    }
    assert!(dir.join("here-contact.png").exists() && dir.join("here-preview.png").exists());

    // The listing counts the frames; each frame's HDR image can be fetched.
    let jobs = c.list_jobs(pb::ListJobsRequest {}).await.unwrap().into_inner().jobs;
    let j = jobs.iter().find(|j| j.id == id).unwrap();
    assert_eq!(
        (sylva_coordinator::job_state::wire_name(j.state), j.frames, j.frames_done),
        ("done", 4, 4),
        "{j:?}"
    );
    let mut frames = Vec::new();
    for i in 0..4 {
        let p = dir.join(format!("fetched-{i}.exr"));
        ok(&[
            "fetch",
            &id,
            "--coordinator",
            &addr,
            "--frame",
            &i.to_string(),
            "-o",
            p.to_str().unwrap(),
        ]);
        frames.push(exr(&p));
    }
    let e = c
        .fetch_result(pb::FetchRequest { id: id.clone(), format: "png".into(), frame: 4 })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");

    // Whole frames side by side (four frames, two workers): each sun was
    // solved once, on the worker that drew its frame.
    assert_eq!(lb_solves(&w1.addr).await + lb_solves(&w2.addr).await, 4);

    // Frame 0's view is the scene's own: it is the frame a plain job renders.
    let single = dir.join("single.png");
    let mut args = vec![
        "submit",
        scene.to_str().unwrap(),
        "--coordinator",
        &addr,
        "-o",
        single.to_str().unwrap(),
        "--exr",
    ];
    args.extend(frame_flags);
    ok(&args);
    let plain = exr(&dir.join("single.exr"));
    let rel = |a: &[f32], b: &[f32]| {
        let diff: f64 = a.iter().zip(b).map(|(x, y)| (x - y).abs() as f64).sum();
        diff / b.iter().map(|y| y.abs() as f64).sum::<f64>().max(1e-9)
    };
    assert!(
        rel(&frames[0], &plain) < 1e-3,
        "frame 0 against the plain frame: {}",
        rel(&frames[0], &plain)
    );
    // The camera moved and the sun sank: the last frame is another picture.
    assert!(rel(&frames[3], &plain) > 0.1, "frame 3 against frame 0: {}", rel(&frames[3], &plain));

    // Final passes over the same sweep at more samples, on the first
    // worker alone: it solves the suns it has not seen, then nothing: the
    // light is kept per sun, whatever else (samples, camera) changes.
    let solo = spawn(&["coordinator", "--listen", "127.0.0.1:0", "--workers", &w1.addr], &[]);
    let pass = |name: &str| {
        let out = dir.join(name);
        let mut args = vec![
            "submit",
            scene.to_str().unwrap(),
            "--coordinator",
            &solo.addr,
            "-o",
            out.to_str().unwrap(),
            "--spp",
            "2",
        ];
        args.extend(frame_flags);
        args.extend(sequence_flags);
        ok(&args);
    };
    let before = lb_solves(&w1.addr).await;
    pass("final.png");
    let second = lb_solves(&w1.addr).await - before;
    assert!(second <= 4, "{second} solves for 4 suns");
    pass("final-again.png");
    assert_eq!(lb_solves(&w1.addr).await - before, second, "the third pass solved again");

    // Bad sequences are refused with the reason, and the farm goes on.
    let b = sylva_scene::bundle::pack(&scene).unwrap();
    let mut bad = spec(64, 32);
    bad.views = vec![pb::FrameView { camera: None, sun_towards: vec![f32::NAN, 1.0, 0.0] }];
    let e = c
        .submit_job(tokio_stream::iter(submission(bad, &b.hash, &b.bytes, b.bytes.len() as u64)))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(
        e.message().contains("frame 0") && e.message().contains("sun_towards"),
        "{}",
        e.message()
    );
    let mut long = spec(64, 32);
    long.views = vec![pb::FrameView::default(); 10_001];
    let e = c
        .submit_job(tokio_stream::iter(submission(long, &b.hash, &b.bytes, b.bytes.len() as u64)))
        .await
        .unwrap_err();
    assert!(e.message().contains("at most 10000"), "{}", e.message());
    let fails = sylva(
        &[
            "submit",
            scene.to_str().unwrap(),
            "--coordinator",
            &addr,
            "--frames",
            "3",
            "--sun-from",
            "95,0",
            "--sun-to",
            "10,0",
        ],
        &[],
    );
    assert!(!fails.status.success());
    assert!(
        String::from_utf8_lossy(&fails.stderr).contains("sequence.sun.from.elevation_deg 95"),
        "{}",
        String::from_utf8_lossy(&fails.stderr)
    );

    drop((w1, w2, coord, solo));
    std::fs::remove_dir_all(&dir).ok();
}
