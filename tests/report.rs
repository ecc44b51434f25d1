//! `helmcap report` through the real binary: two synthetic 30-frame takes replayed with
//! `--export usd` give a day page naming both and one page per take; every page is
//! self-contained (no script, no URL to load), has its SVG plots and embedded PNGs (camera
//! images with points when the take names its session, mesh renders always); a take
//! folder that misses files still gets a page saying so, and a folder that is not a take
//! is refused by name. When Chromium is installed, each page is loaded headless: it must
//! log no console error and its screenshot must show a page, not a blank.

#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{helmcap, ok};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A synthetic session `dir/sessions/<name>` of `frames` frames (expression seed `seed`)
/// replayed into `dir/<name>` with `--export usd`; returns (session, take folder).
fn take(dir: &Path, name: &str, seed: u64, frames: usize) -> (PathBuf, PathBuf) {
    let session = dir.join("sessions").join(name);
    let seed = seed.to_string();
    let frames = frames.to_string();
    ok(&helmcap(&[
        "synth",
        "--out",
        s(&session),
        "-n",
        &frames,
        "--seed",
        &seed,
    ]));
    let out = dir.join(name);
    ok(&helmcap(&[
        "replay",
        s(&session),
        "--out",
        s(&out),
        "--cache-dir",
        s(&dir.join("cache")),
        "--export",
        "usd",
        "--quiet",
    ]));
    (session, out)
}

/// The payloads of every `data:image/png;base64,` URL in `page`, decoded.
fn embedded_pngs(page: &str) -> Vec<Vec<u8>> {
    const KEY: &str = "data:image/png;base64,";
    page.match_indices(KEY)
        .map(|(i, _)| {
            let rest = &page[i + KEY.len()..];
            let end = rest.find('"').unwrap();
            base64_decode(&rest[..end])
        })
        .collect()
}

/// Standard base64 with padding.
fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let mut out = Vec::new();
    for chunk in text.as_bytes().chunks(4) {
        let data: Vec<u8> = chunk.iter().copied().filter(|&c| c != b'=').collect();
        let n = data
            .iter()
            .enumerate()
            .fold(0u32, |n, (i, &c)| n | (value(c) << (18 - 6 * i)));
        for k in 0..data.len().saturating_sub(1) {
            out.push((n >> (16 - 8 * k)) as u8);
        }
    }
    out
}

/// A page must load nothing from anywhere and run nothing.
fn assert_self_contained(name: &str, page: &str) {
    let lower = page.to_ascii_lowercase();
    for bad in [
        "src=\"http",
        "href=\"http",
        "src=\"//",
        "href=\"//",
        "url(http",
        "<script",
        "<link",
        "@import",
    ] {
        assert!(!lower.contains(bad), "{name}: has {bad}");
    }
    // Every src and href is a data URL or a page of the report.
    for attr in ["src=\"", "href=\""] {
        for (i, _) in page.match_indices(attr) {
            let value = &page[i + attr.len()..];
            assert!(
                value.starts_with("data:image/png;base64,")
                    || value.split('"').next().unwrap().ends_with(".html"),
                "{name}: {attr}{}",
                &value[..value.len().min(40)]
            );
        }
    }
}

#[test]
fn dailies_report_of_two_takes() {
    let dir = tempfile::tempdir().unwrap();
    let (session_a, take_a) = take(dir.path(), "take_a", 1, 30);
    let (_, take_b) = take(dir.path(), "take_b", 2, 30);
    // Take A names its session (written here if replay does not write take.json);
    // take B has none, so its sheet shows the mesh renders only and says why.
    let json_a = take_a.join("take.json");
    if !json_a.is_file() {
        let text = format!("{{\"take\": \"take_a\", \"session\": {:?}}}", s(&session_a));
        std::fs::write(&json_a, text).unwrap();
    }
    let _ = std::fs::remove_file(take_b.join("take.json"));

    let report = dir.path().join("report");
    let out = helmcap(&[
        "report",
        s(&take_a),
        s(&take_b),
        "--out",
        s(&report),
        "--day",
        "Day 3 <unit>",
        "--quiet",
    ]);
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("report of 2 takes"), "{stdout}");

    let index = std::fs::read_to_string(report.join("index.html")).unwrap();
    let page_a = std::fs::read_to_string(report.join("take_a.html")).unwrap();
    let page_b = std::fs::read_to_string(report.join("take_b.html")).unwrap();
    let mut total = 0;
    for entry in std::fs::read_dir(&report).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name().to_string_lossy().into_owned();
        assert!(!name.starts_with('.'), "temporary file {name} left behind");
        total += entry.metadata().unwrap().len();
    }
    println!("two-take report: {total} bytes");

    // The day page: both takes, linked, with their numbers and the escaped title.
    assert!(index.contains("Day 3 &lt;unit&gt;"));
    for t in ["take_a", "take_b"] {
        assert!(
            index.contains(&format!("href=\"{t}.html\"")),
            "no link to {t}"
        );
        assert!(index.contains(&format!(">{t}</a>")), "{t} not named");
    }
    assert!(index.contains("<svg"), "no summary plot");
    assert!(index.matches("<tr>").count() >= 3, "header and two takes");

    for (name, page) in [
        ("index.html", &index),
        ("take_a.html", &page_a),
        ("take_b.html", &page_b),
    ] {
        assert_self_contained(name, page);
    }
    for page in [&page_a, &page_b] {
        // Coverage, confidence and head-pose plots at least.
        assert!(page.matches("<svg").count() >= 3, "plots missing");
        assert!(page.contains("Marker coverage") && page.contains("Latency"));
        assert!(page.contains("end to end"));
        assert!(page.contains("href=\"index.html\""));
        // The synthetic session has ground truth: the residual section reports it.
        assert!(page.contains("ground truth") || page.contains("rig_weights.csv"));
    }
    // Take A: 4 camera images and 4 mesh renders; take B: the renders and why.
    let pngs_a = embedded_pngs(&page_a);
    let pngs_b = embedded_pngs(&page_b);
    assert_eq!(pngs_a.len(), 8, "take A images");
    assert_eq!(pngs_b.len(), 4, "take B images");
    assert!(page_b.contains("no take.json"));
    assert!(page_a.contains("labeled points"));
    for png in pngs_a.iter().chain(&pngs_b) {
        let img = image::load_from_memory(png).unwrap().to_rgb8();
        assert!(img.width() >= 100 && img.height() >= 100);
        let first = *img.get_pixel(0, 0);
        let differing = img.pixels().filter(|p| **p != first).count();
        assert!(
            differing * 10 > img.pixels().len(),
            "an embedded image is mostly one colour"
        );
    }

    browser_check(
        &report,
        &["index.html", "take_a.html", "take_b.html"],
        dir.path(),
    );
}

/// A take folder without `bundles.csv`, `tracks.csv` and meshes still gets a page that
/// names what is missing; a folder without `metrics.json` is refused by name before
/// anything is written.
#[test]
fn missing_files_and_folders_that_are_not_takes() {
    let dir = tempfile::tempdir().unwrap();
    let (_, t) = take(dir.path(), "thin", 3, 12);
    for f in ["bundles.csv", "tracks.csv", "mesh.usda", "take.json"] {
        let _ = std::fs::remove_file(t.join(f));
    }
    let report = dir.path().join("report");
    ok(&helmcap(&["report", s(&t), "--out", s(&report), "--quiet"]));
    let page = std::fs::read_to_string(report.join("thin.html")).unwrap();
    for expected in [
        "bundles.csv: missing",
        "tracks.csv: missing",
        "no mesh export",
        "Head pose",
    ] {
        assert!(page.contains(expected), "page lacks {expected:?}");
    }
    assert_self_contained("thin.html", &page);

    let empty = dir.path().join("not-a-take");
    std::fs::create_dir_all(&empty).unwrap();
    let other = dir.path().join("report2");
    let out = helmcap(&["report", s(&t), s(&empty), "--out", s(&other)]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("not-a-take") && err.contains("not a take folder"),
        "{err}"
    );
    assert!(
        !other.join("thin.html").exists(),
        "pages written before the check"
    );
}

/// Chromium, when installed: `/usr/bin/chromium`, else `chromium` or
/// `chromium-browser` on `PATH`.
fn chromium() -> Option<PathBuf> {
    let fixed = Path::new("/usr/bin/chromium");
    if fixed.is_file() {
        return Some(fixed.to_path_buf());
    }
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|d| [d.join("chromium"), d.join("chromium-browser")])
        .find(|p| p.is_file())
}

/// Runs `cmd` for at most `limit`, returning its output (`None` on a timeout).
fn run_with_timeout(mut cmd: Command, limit: Duration) -> Option<Output> {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Drain the pipes on threads so a chatty browser cannot block on a full pipe.
    let mut so = child.stdout.take().unwrap();
    let mut se = child.stderr.take().unwrap();
    let out_t = std::thread::spawn(move || {
        let mut b = Vec::new();
        std::io::Read::read_to_end(&mut so, &mut b).ok();
        b
    });
    let err_t = std::thread::spawn(move || {
        let mut b = Vec::new();
        std::io::Read::read_to_end(&mut se, &mut b).ok();
        b
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    Some(Output {
        status,
        stdout: out_t.join().unwrap(),
        stderr: err_t.join().unwrap(),
    })
}

/// Console errors of a headless Chromium run: lines of its log that report a page
/// script error, a console message (`INFO:CONSOLE:1] "...", source: file:///...`) or a
/// resource that failed to load.
fn console_errors(stderr: &str) -> Vec<String> {
    stderr
        .lines()
        .filter(|l| {
            l.contains("Uncaught")
                || l.contains(":CONSOLE")
                || l.contains("Failed to load resource")
                || l.contains("net::ERR_")
        })
        .map(str::to_string)
        .collect()
}

/// Loads each page in headless Chromium: the DOM must come back with the page's plots,
/// the log must hold no console error, and the screenshot must not be blank.
fn browser_check(report: &Path, pages: &[&str], scratch: &Path) {
    let Some(chromium) = chromium() else {
        println!(
            "skipping the browser check: no chromium (/usr/bin/chromium or on PATH; \
             scripts/setup.sh installs Debian's chromium)"
        );
        return;
    };
    let profile = scratch.join("chromium-profile");
    for page in pages {
        let path = report.join(page).canonicalize().unwrap();
        let url = format!("file://{}", path.display());
        let shot = scratch.join(format!("{page}.png"));
        let base = |extra: &[&str]| {
            let mut c = Command::new(&chromium);
            c.args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--enable-logging=stderr",
                "--v=0",
                "--window-size=1280,2000",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .args(extra)
            .arg(&url);
            c
        };
        let Some(dom) = run_with_timeout(base(&["--dump-dom"]), Duration::from_secs(120)) else {
            panic!("{page}: chromium --dump-dom did not finish in 120 s");
        };
        let dom_err = String::from_utf8_lossy(&dom.stderr);
        if !dom.status.success() && dom.stdout.is_empty() {
            // A browser that cannot start here (no display libraries, a locked-down
            // container) is not the page's fault.
            println!(
                "skipping the browser check: chromium could not run: {}",
                dom_err.lines().last().unwrap_or_default()
            );
            return;
        }
        let dom_text = String::from_utf8_lossy(&dom.stdout);
        assert!(
            dom_text.contains("<svg"),
            "{page}: the DOM Chromium built has no SVG"
        );
        let shot_arg = format!("--screenshot={}", shot.display());
        let Some(run) = run_with_timeout(base(&[&shot_arg]), Duration::from_secs(120)) else {
            panic!("{page}: chromium --screenshot did not finish in 120 s");
        };
        let shot_err = String::from_utf8_lossy(&run.stderr);
        let errors: Vec<String> = console_errors(&dom_err)
            .into_iter()
            .chain(console_errors(&shot_err))
            .collect();
        assert!(
            errors.is_empty(),
            "{page}: console errors:\n{}",
            errors.join("\n")
        );
        assert!(
            shot.is_file(),
            "{page}: no screenshot ({})\n{shot_err}",
            run.status
        );
        let img = image::open(&shot).unwrap().to_rgb8();
        let pixels = img.pixels().len();
        let not_white = img
            .pixels()
            .filter(|p| p.0.iter().any(|&c| c < 240))
            .count();
        let colours: std::collections::HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        println!(
            "{page}: screenshot {}x{}, {:.1} % not white, {} colours",
            img.width(),
            img.height(),
            100.0 * not_white as f64 / pixels as f64,
            colours.len()
        );
        // Text, tables and plots cover a few per cent of a 1280 × 2000 page at the
        // least (a blank page: none); antialiased text and plots give hundreds of
        // colours, a blank or error page a handful.
        assert!(
            not_white * 100 > pixels,
            "{page}: screenshot nearly blank ({not_white} of {pixels} pixels not white)"
        );
        assert!(
            colours.len() > 64,
            "{page}: screenshot has only {} colours",
            colours.len()
        );
    }
}
