//! `strata view`: the progressive passes against `render`'s image, the Host-header guard
//! over raw HTTP, and the page in a real headless Chromium driven over WebDriver (the image
//! appears, a click shows a prim's slot stack, a saved substance edit changes the image, a
//! syntax error shows the diagnostic and keeps the last image).
//!
//! The browser test needs Debian's `chromium` and `chromium-driver` (`.ci/run` installs
//! them); where they are missing it skips with a printed reason, unless `CI` is set.

use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use strata::render::RenderSettings;
use strata::render::geometry::displace::DicingOptions;
use strata::render::scene::SceneOptions;
use strata::session::{Pass, SceneSource, Session, SessionOptions};
use strata::view::progressive::{Accumulator, sample_ranges};

fn prepared(settings: &RenderSettings) -> Session {
    let mut session = Session::open(SceneSource::Default, SessionOptions::default());
    let options = SceneOptions {
        dicing: DicingOptions { resolution: (settings.width, settings.height), ..DicingOptions::default() },
        ..SceneOptions::default()
    };
    assert!(session.prepare(&options).is_some(), "{}", session.diagnostics().render(session.sources()));
    session
}

#[test]
fn sample_ranges_double_up_to_spp() {
    assert_eq!(sample_ranges(1), vec![0..1]);
    assert_eq!(sample_ranges(6), vec![0..1, 1..2, 2..4, 4..6]);
    assert_eq!(sample_ranges(64).last(), Some(&(32..64)));
}

/// The view's progressive passes (bands of rows over doubling sample ranges) end on the image
/// one `render` pass writes at the same spp and seed, every channel bit for bit; and the
/// images on the way hold 1, 2, 4 … samples.
#[test]
fn progressive_passes_converge_to_the_render_bit_for_bit() {
    // 40 rows: two full bands and a short one.
    let settings = RenderSettings { width: 48, height: 40, spp: 6, seed: 3, ..RenderSettings::default() };
    let mut session = prepared(&settings);
    let (reference, _) = session.render(&Pass::full(settings.clone()), None).expect("render");
    let mut passes = Accumulator::new(settings.clone());
    let mut seen = Vec::new();
    while !passes.done() {
        if passes.step(&mut session).expect("pass") {
            seen.push(passes.samples());
        }
    }
    assert_eq!(seen, vec![1, 2, 4, 6]);
    let image = passes.image(&session).expect("an image").expect("image from sums");
    assert_eq!(image.channels.len(), reference.channels.len());
    for (a, b) in image.channels.iter().zip(&reference.channels) {
        assert!(a == b, "channel {} differs from the render's", a.name);
    }
    // An image of fewer samples is a different (noisier) image: the check above can fail.
    let (fewer, _) = session.render(&Pass::full(RenderSettings { spp: 5, ..settings }), None).expect("render at 5 spp");
    assert!(fewer.channels[0] != reference.channels[0]);
}

/// A running `strata view`, stopped on drop.
struct View {
    child: Child,
    url: String,
    port: u16,
}

impl View {
    fn start(scene: &Path, extra: &[&str]) -> View {
        let mut child = Command::new(env!("CARGO_BIN_EXE_strata"))
            .arg("view")
            .arg(scene)
            .args(["--port", "0", "--res", "160x120", "--spp", "4"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("strata view starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout")).read_line(&mut line).expect("a line");
        let url = line.trim().strip_prefix("strata view: ").unwrap_or_else(|| panic!("no URL in `{line}`")).to_string();
        let port = url.trim_end_matches('/').rsplit(':').next().and_then(|p| p.parse().ok()).expect("a port");
        View { child, url, port }
    }
}

impl Drop for View {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// One HTTP/1.1 request over a fresh connection; returns the status and the body.
fn http(port: u16, method: &str, path: &str, host: &str, body: Option<&str>) -> (u16, Vec<u8>) {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).expect("connect");
    stream.set_read_timeout(Some(Duration::from_secs(180))).unwrap();
    let body = body.unwrap_or("");
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    // Read the head, then exactly the body it announces: a server may keep the connection open.
    let mut raw = Vec::new();
    let mut buffer = [0u8; 65536];
    let split = loop {
        if let Some(split) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
            break split;
        }
        let n = stream.read(&mut buffer).expect("response head");
        assert!(n > 0, "connection closed before the response head");
        raw.extend_from_slice(&buffer[..n]);
    };
    let head = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).expect("status");
    let length =
        head.lines().find_map(|l| l.strip_prefix("content-length:")).and_then(|n| n.trim().parse::<usize>().ok());
    let chunked = head.contains("transfer-encoding: chunked");
    let mut payload = raw[split + 4..].to_vec();
    loop {
        let complete = match length {
            Some(n) => payload.len() >= n,
            None if chunked => payload.ends_with(b"0\r\n\r\n"),
            None => false,
        };
        if complete {
            break;
        }
        let n = stream.read(&mut buffer).expect("response body");
        if n == 0 {
            break;
        }
        payload.extend_from_slice(&buffer[..n]);
    }
    if chunked {
        payload = dechunk(&payload);
    }
    (status, payload)
}

fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(end) = data.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(String::from_utf8_lossy(&data[..end]).trim(), 16).unwrap_or(0);
        if size == 0 {
            break;
        }
        out.extend_from_slice(&data[end + 2..end + 2 + size]);
        data = &data[end + 4 + size..];
    }
    out
}

fn scene_dir() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = strata::session::write_split_default_scene(dir.path()).expect("scene written");
    (dir, scene)
}

/// Requests naming another host (DNS rebinding) or coming from another site's page are
/// refused; the view's own address is served.
#[test]
fn requests_for_another_host_or_origin_are_refused() {
    let (_dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    let own = format!("127.0.0.1:{}", view.port);
    let (status, page) = http(view.port, "GET", "/", &own, None);
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&page).contains("strata view"));
    for host in [format!("evil.example:{}", view.port), format!("localhost:{}", view.port), "127.0.0.1".into()] {
        let (status, body) = http(view.port, "GET", "/", &host, None);
        assert_eq!(status, 403, "Host: {host} was served");
        assert!(String::from_utf8_lossy(&body).contains("refused"));
    }
    let mut stream = TcpStream::connect(("127.0.0.1", view.port)).unwrap();
    write!(
        stream,
        "POST /camera HTTP/1.1\r\nHost: {own}\r\nOrigin: http://evil.example\r\nConnection: close\r\n\
         Content-Length: 30\r\n\r\n{{\"kind\":\"dolly\",\"factor\":0.5}}"
    )
    .unwrap();
    let mut response = String::new();
    stream.read_to_string(&mut response).unwrap();
    assert!(response.starts_with("HTTP/1.1 403"), "{response}");
    assert!(view.url.starts_with("http://127.0.0.1:"));
}

// ---- WebDriver ----------------------------------------------------------------------------

/// Chromium and its driver, or why the browser test cannot run here.
fn browser() -> Result<(PathBuf, PathBuf), String> {
    let find = |names: &[&str]| names.iter().map(PathBuf::from).find(|p| p.exists());
    let chromium = find(&["/usr/bin/chromium", "/usr/bin/chromium-browser"]);
    let driver = find(&["/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver"]);
    match (chromium, driver) {
        (Some(c), Some(d)) => Ok((c, d)),
        _ => Err("chromium and chromium-driver are not installed (apt-get install chromium chromium-driver)".into()),
    }
}

/// A WebDriver session in headless Chromium.
struct Browser {
    driver: Child,
    port: u16,
    session: String,
    _profile: tempfile::TempDir,
}

impl Browser {
    fn start(chromium: &Path, chromedriver: &Path) -> Browser {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let driver = Command::new(chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let deadline = Instant::now() + Duration::from_secs(30);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "chromedriver did not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        let profile = tempfile::tempdir().unwrap();
        let args = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--window-size=1280,800",
        ]
        .iter()
        .map(|a| a.to_string())
        .chain([format!("--user-data-dir={}", profile.path().display())])
        .collect::<Vec<_>>();
        let mut browser = Browser { driver, port, session: String::new(), _profile: profile };
        let caps = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": { "binary": chromium.display().to_string(), "args": args }
        }}});
        let answer = browser.call("POST", "/session", Some(caps));
        browser.session = answer["sessionId"].as_str().unwrap_or_else(|| panic!("no session: {answer}")).to_string();
        browser
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let body = body.map(|b| b.to_string());
        let (_, bytes) = http(self.port, method, path, &format!("127.0.0.1:{}", self.port), body.as_deref());
        let value: Value = serde_json::from_slice(&bytes).expect("WebDriver JSON");
        value["value"].clone()
    }

    fn session_call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        self.call(method, &format!("/session/{}{path}", self.session), body)
    }

    fn script(&self, script: &str) -> Value {
        self.session_call("POST", "/execute/sync", Some(json!({ "script": script, "args": [] })))
    }

    /// Runs `script` until it returns something other than `null`/`false`.
    fn wait_for(&self, what: &str, script: &str) -> Value {
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let value = self.script(script);
            if !value.is_null() && value != Value::Bool(false) {
                return value;
            }
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let _ = self.call("DELETE", &format!("/session/{}", self.session), None);
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// A hash of the displayed image's pixels once it is converged (and loaded) after at least
/// `edits` edits, else `null`.
fn converged_image(edits: u64) -> String {
    format!(
        "const img = document.getElementById('frame');
         const d = img.dataset;
         if (Number(d.edits) < {edits} || d.samples !== '4' || !img.complete || img.naturalWidth === 0
             || !img.src.endsWith('g=' + d.generation)) return null;
         const c = document.createElement('canvas');
         c.width = img.naturalWidth; c.height = img.naturalHeight;
         const g = c.getContext('2d'); g.drawImage(img, 0, 0);
         const px = g.getImageData(0, 0, c.width, c.height).data;
         let h = 2166136261;
         for (let i = 0; i < px.length; i++) h = Math.imul(h ^ px[i], 16777619) >>> 0;
         return c.width + 'x' + c.height + ':' + h;"
    )
}

#[test]
fn the_page_renders_inspects_and_follows_edits_in_chromium() {
    let (chromium, chromedriver) = match browser() {
        Ok(found) => found,
        Err(reason) if std::env::var_os("CI").is_none() => {
            eprintln!("skipped: {reason}");
            return;
        }
        Err(reason) => panic!("CI must install the browser: {reason}"),
    };
    let (dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    let browser = Browser::start(&chromium, &chromedriver);
    browser.session_call("POST", "/url", Some(json!({ "url": view.url })));

    // The image appears and converges.
    let first = browser.wait_for("the converged image", &converged_image(0));
    assert!(first.as_str().unwrap().starts_with("160x120:"), "{first}");

    // A click in the middle of the image, on the centre ball, shows its slot stack.
    let centre = browser.script(
        "const r = document.getElementById('frame').getBoundingClientRect();
         return [Math.round(r.left + r.width / 2), Math.round(r.top + r.height / 2)];",
    );
    let click = json!({ "actions": [{ "type": "pointer", "id": "mouse", "parameters": { "pointerType": "mouse" },
        "actions": [
            { "type": "pointerMove", "duration": 0, "x": centre[0], "y": centre[1], "origin": "viewport" },
            { "type": "pointerDown", "button": 0 }, { "type": "pointerUp", "button": 0 }
        ] }] });
    let clicked = browser.session_call("POST", "/actions", Some(click));
    assert!(clicked.is_null(), "the click failed: {clicked}");
    let stack = browser.wait_for(
        "the inspector",
        "const t = document.getElementById('pick-stack'); const p = document.getElementById('pick-prim');
         return t && p ? p.textContent + '\\n' + t.innerText : null;",
    );
    let stack = stack.as_str().unwrap();
    assert_eq!(stack.lines().next(), Some("/World/Balls/Center"), "{stack}");
    for row in expected_stack_rows(&scene, "/World/Balls/Center") {
        assert!(stack.contains(&row), "inspector shows\n{stack}\nexpected a row `{row}`");
    }

    // Saving an edited substance file changes the image.
    let dirt = dir.path().join("dirt.ash");
    let text = std::fs::read_to_string(&dirt).unwrap();
    let edited = text.replacen("0.2, 0.15, 0.1", "0.1, 0.3, 0.6", 1);
    assert_ne!(edited, text, "the dirt colour to edit");
    let saved = Instant::now();
    std::fs::write(&dirt, &edited).unwrap();
    browser.wait_for("a new preview", "return document.getElementById('frame').dataset.edits !== '0' || null;");
    let seen_ms = saved.elapsed().as_secs_f64() * 1e3;
    let after = browser.wait_for("the edited image", &converged_image(1));
    assert_ne!(after, first, "the edit did not change the image");
    let reported = browser.script("return document.getElementById('update').textContent;");
    eprintln!("save → page saw the edit: {seen_ms:.0} ms (load {}); view reports: {reported}", load());

    // A syntax error shows the diagnostic, and the last good image stays.
    std::fs::write(&dirt, edited.replacen("substance dirt {", "substance dirt { = ", 1)).unwrap();
    let shown = browser.wait_for(
        "the diagnostic",
        "const d = document.getElementById('diagnostics');
         return d.dataset.failed === 'true' && d.style.display !== 'none' ? d.textContent : null;",
    );
    let shown = shown.as_str().unwrap();
    assert!(shown.contains("dirt.ash:") && shown.contains("error"), "{shown}");
    let edits = edits_seen(&browser);
    assert_eq!(browser.wait_for("the kept image", &converged_image(edits)), after, "the last good image was not kept");

    // Fixing it renders again and clears the diagnostic.
    std::fs::write(&dirt, &text).unwrap();
    browser.wait_for(
        "the fix",
        &format!("return Number(document.getElementById('frame').dataset.edits) > {edits} || null;"),
    );
    let fixed = browser.wait_for("the fixed image", &converged_image(edits + 1));
    assert_eq!(fixed, first, "the original file renders the original image");
    let diagnostics = browser.script("return document.getElementById('diagnostics').style.display;");
    assert_eq!(diagnostics, "none");

    if let Some(path) = std::env::var_os("STRATA_VIEW_SCREENSHOT") {
        let png = browser.session_call("GET", "/screenshot", None);
        std::fs::write(path, base64_decode(png.as_str().unwrap())).unwrap();
    }
}

/// The slot and override rows `strata layers` composes for `prim`, as the inspector's table
/// shows them (`slot<TAB>material<TAB>bound at`).
fn expected_stack_rows(scene: &Path, prim: &str) -> Vec<String> {
    let mut session = Session::open(SceneSource::File(scene.to_path_buf()), SessionOptions::default());
    let stacks = session.layer_stacks();
    let stack = stacks.iter().find(|s| s.prim == prim).unwrap_or_else(|| panic!("`{prim}` is not a renderable prim"));
    assert!(stack.layers.len() >= 2, "the centre ball has a layered stack");
    let row = |slot: String, applied: &strata::compose::slots::Applied| {
        format!("{slot}\t{}\t{}", applied.material, applied.bound_at)
    };
    let mut rows = Vec::new();
    for layer in &stack.layers {
        rows.push(row(layer.slot.name(), &layer.applied));
        rows.extend(layer.overrides.iter().map(|o| row(o.slot.name(), &o.applied)));
    }
    rows
}

fn edits_seen(browser: &Browser) -> u64 {
    let edits = browser.script("return document.getElementById('frame').dataset.edits;");
    edits.as_str().and_then(|e| e.parse().ok()).expect("edits")
}

fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_default()
}

fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let digits: Vec<u8> = text.bytes().filter_map(value).collect();
    digits
        .chunks(4)
        .flat_map(|c| {
            let n = c.iter().enumerate().fold(0u32, |n, (i, &d)| n | (d as u32) << (18 - 6 * i));
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            bytes.into_iter().take(c.len().saturating_sub(1))
        })
        .collect()
}
