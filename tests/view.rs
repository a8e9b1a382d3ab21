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
    prepared_from(SceneSource::Default, settings)
}

fn prepared_from(source: SceneSource, settings: &RenderSettings) -> Session {
    let mut session = Session::open(source, SessionOptions::default());
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

/// Chromium with its driver, or `None` (with the reason printed) where they are missing
/// outside CI.
fn browser_or_skip() -> Option<Browser> {
    match browser() {
        Ok((chromium, chromedriver)) => Some(Browser::start(&chromium, &chromedriver)),
        Err(reason) if std::env::var_os("CI").is_none() => {
            eprintln!("skipped: {reason}");
            None
        }
        Err(reason) => panic!("CI must install the browser: {reason}"),
    }
}

/// A real mouse click in the middle of the image (on the default scene's centre ball).
fn click_centre(browser: &Browser) {
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
}

#[test]
fn the_page_renders_inspects_and_follows_edits_in_chromium() {
    let Some(browser) = browser_or_skip() else { return };
    let (dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    browser.session_call("POST", "/url", Some(json!({ "url": view.url })));

    // The image appears and converges.
    let first = browser.wait_for("the converged image", &converged_image(0));
    assert!(first.as_str().unwrap().starts_with("160x120:"), "{first}");

    // A click in the middle of the image, on the centre ball, shows its slot stack.
    click_centre(&browser);
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

/// Look edits from the page, in Chromium: muting the dirt slot changes the image and
/// unmuting brings the original back bit for bit; the inspector lists the centre ball's
/// inputs, and moving the dirt's coverage slider changes the image; the edit is written as an
/// override layer that usd-core reads. Prints the input-edit-to-image time.
#[test]
fn look_edits_from_the_page_change_the_image_and_undo_bit_for_bit() {
    let Some(browser) = browser_or_skip() else { return };
    let (_dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    browser.session_call("POST", "/url", Some(json!({ "url": view.url })));
    let first = browser.wait_for("the converged image", &converged_image(0));

    // Mute the dirt slot (`050`, scene-wide), then unmute it.
    let toggle =
        "const b = document.querySelector('[data-mute=\"050\"]'); if (!b) return null; b.click(); return true;";
    browser.wait_for("the mute checkbox", toggle);
    let muted = browser.wait_for("the muted image", &converged_image(1));
    assert_ne!(muted, first, "muting the dirt did not change the image");
    assert_eq!(browser.script("return document.getElementById('slots').dataset.muted;"), "050");
    browser.wait_for("the mute checkbox", toggle);
    let unmuted = browser.wait_for("the unmuted image", &converged_image(2));
    assert_eq!(unmuted, first, "unmuting did not restore the original image bit for bit");

    // The inspector lists the inputs of the centre ball's layers; the paint override drives
    // the clay's colour, the dirt's coverage has a slider.
    click_centre(&browser);
    let inputs = browser
        .wait_for("the inputs", "const t = document.getElementById('pick-inputs'); return t ? t.innerText : null;");
    let inputs = inputs.as_str().unwrap();
    assert!(inputs.contains("/Looks/Dirt") && inputs.contains("coverage"), "{inputs}");
    assert!(inputs.contains("driven by /Looks/RedPaint"), "{inputs}");
    let slide = "const s = [...document.querySelectorAll('input[type=range]')]
                   .find((e) => e.dataset.input === '/Looks/Dirt.coverage');
                 if (!s) return null;
                 s.value = 0.25; s.dispatchEvent(new Event('change')); return true;";
    let compiled = wait_status(view.port, "the status", |_| true)["materials_compiled"].as_u64().expect("a count");
    let moved = Instant::now();
    browser.wait_for("the coverage slider", slide);
    browser
        .wait_for("the edit's preview", "return Number(document.getElementById('frame').dataset.edits) >= 3 || null;");
    let seen_ms = moved.elapsed().as_secs_f64() * 1e3;
    let edited = browser.wait_for("the edited image", &converged_image(3));
    assert_ne!(edited, first, "the coverage edit did not change the image");
    // The coverage is a live input: the edit rewrote a parameter block and compiled nothing.
    let status = wait_status(view.port, "the status", |_| true);
    assert_eq!(status["materials_compiled"].as_u64(), Some(compiled), "the slider recompiled: {status}");
    assert!(status["parameter_writes"].as_u64() >= Some(1), "{status}");
    let reported = browser.script("return document.getElementById('update').textContent;");
    eprintln!(
        "input edit → page saw the preview: {seen_ms:.0} ms (load {}); view reports: {reported}; server-side {} ms",
        load(),
        status["input_ms"]
    );

    // Written as an override layer beside the scene; the scene file is untouched.
    let original = std::fs::read_to_string(&scene).unwrap();
    browser.script("document.getElementById('write-look').click(); return true;");
    let written = browser.wait_for(
        "the override layer",
        "const o = document.getElementById('look-written'); return o.dataset.ok === 'true' ? o.textContent : null;",
    );
    let path = PathBuf::from(written.as_str().unwrap().strip_prefix("wrote ").expect("a path"));
    assert_eq!(path.file_name().unwrap(), "default.look.usda");
    assert_eq!(std::fs::read_to_string(&scene).unwrap(), original);
    if let Some(value) = usd_value(&path, &scene, "/Looks/Dirt/Surface.inputs:coverage") {
        assert!((value - 0.25).abs() < 1e-6, "usd-core reads {value}");
    }
}

/// An input set over HTTP renders, in a session opened on the written override layer
/// sublayered above the scene, what the view's session renders after the same
/// `Change::Value`, bit for bit; usd-core reads the value from that layer stack.
#[test]
fn an_override_layer_holds_the_input_edits_as_usd_reads_them() {
    let (dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    let own = format!("127.0.0.1:{}", view.port);
    let (status, _) = http(view.port, "POST", "/look/write", &own, None);
    assert_eq!(status, 409, "nothing to write before an edit");
    let edit = r#"{"prim": "/Looks/Dirt/Surface", "input": "dirt_color", "type": "color", "value": [0.1, 0.3, 0.6]}"#;
    assert_eq!(http(view.port, "POST", "/input", &own, Some(edit)).0, 204);
    let bad = r#"{"prim": "/Looks/Dirt/Surface", "input": "coverage", "type": "float", "value": "lots"}"#;
    assert_eq!(http(view.port, "POST", "/input", &own, Some(bad)).0, 400);
    // The edit is applied before the layer is written (commands are handled in order).
    let (status, body) = http(view.port, "POST", "/look/write", &own, None);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    let answer: Value = serde_json::from_slice(&body).unwrap();
    let layer = PathBuf::from(answer["path"].as_str().unwrap());
    let text = std::fs::read_to_string(&layer).unwrap();
    assert!(
        text.contains("over \"Surface\"") && text.contains("color3f inputs:dirt_color = (0.1, 0.3, 0.6)"),
        "{text}"
    );

    let root = dir.path().join("root.usda");
    std::fs::write(
        &root,
        "#usda 1.0\n(\n    defaultPrim = \"World\"\n    subLayers = [@./default.look.usda@, @./default.usda@]\n)\n",
    )
    .unwrap();
    let settings = RenderSettings { width: 48, height: 36, spp: 2, seed: 5, ..RenderSettings::default() };
    let mut authored = prepared_from(SceneSource::File(root), &settings);
    let mut edited = prepared_from(SceneSource::File(scene.clone()), &settings);
    let report = edited.apply_change(&strata::session::Change::Value {
        prim: "/Looks/Dirt/Surface".into(),
        attribute: "inputs:dirt_color".into(),
        type_name: "color3f".into(),
        value: strata::scene::Value::Tuple(vec![0.1, 0.3, 0.6]),
    });
    assert!(!report.failed && report.recompiled > 0, "{report:?}");
    let (a, _) = authored.render(&Pass::full(settings.clone()), None).unwrap();
    let (b, _) = edited.render(&Pass::full(settings.clone()), None).unwrap();
    let (c, _) =
        prepared_from(SceneSource::File(scene.clone()), &settings).render(&Pass::full(settings), None).unwrap();
    assert!(a == b, "the layer renders as the in-memory edit, bit for bit");
    assert!(a != c, "the edit shows");
    if let Some(green) = usd_value(&layer, &scene, "/Looks/Dirt/Surface.inputs:dirt_color[1]") {
        assert!((green - 0.3).abs() < 1e-6, "usd-core reads {green}");
    }
}

/// The view's status once `done` holds for it (long polls).
fn wait_status(port: u16, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let own = format!("127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(180);
    let mut after = 0;
    loop {
        let (_, body) = http(port, "GET", &format!("/status?after={after}"), &own, None);
        let status: Value = serde_json::from_slice(&body).expect("status JSON");
        if done(&status) {
            return status;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}: {status}");
        after = status["generation"].as_u64().unwrap_or(0);
    }
}

/// A pick gives each layer's share of the rule-5 pick at that pixel (summing to one with the
/// transparency, over the slots of the prim's stack), and selects the prim: the channel list
/// gains its Cryptomatte mattes, which cover the picked pixel fully and the background not.
#[test]
fn a_pick_gives_layer_shares_and_the_selections_mattes() {
    let (_dir, scene) = scene_dir();
    let view = View::start(&scene, &[]);
    let own = format!("127.0.0.1:{}", view.port);
    wait_status(view.port, "the converged image", |s| s["samples"] == 4);
    let (_, body) = http(view.port, "GET", "/pick?x=80&y=60", &own, None);
    let pick: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(pick["prim"], "/World/Balls/Center");
    let shares = pick["shares"]["layers"].as_array().expect("shares");
    let slots: Vec<&str> = shares.iter().map(|l| l["slot"].as_str().unwrap()).collect();
    assert_eq!(slots, ["000", "050"], "{pick}");
    let total: f64 = shares.iter().map(|l| l["share"].as_f64().unwrap()).sum::<f64>()
        + pick["shares"]["transparent"].as_f64().unwrap();
    assert!((total - 1.0).abs() < 1e-5, "shares sum to {total}");
    assert!(shares.iter().all(|l| (0.0..=1.0).contains(&l["share"].as_f64().unwrap())));

    let status = wait_status(view.port, "the selection", |s| s["selected"] == "/World/Balls/Center");
    for layer in ["CryptoObject", "CryptoMaterial"] {
        let channel = format!("matte:{layer}");
        assert!(status["channels"].as_array().unwrap().iter().any(|c| c == &channel), "{status}");
        let (code, png) = http(view.port, "GET", &format!("/frame.png?channel={channel}"), &own, None);
        assert_eq!(code, 200);
        let decoder = png::Decoder::new(std::io::Cursor::new(png));
        let mut reader = decoder.read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut pixels).unwrap();
        let at = |x: usize, y: usize| pixels[(y * 160 + x) * 3];
        assert_eq!(at(80, 60), 255, "{layer}: the picked pixel is covered");
        assert_eq!(at(0, 0), 0, "{layer}: the corner is not the ball");
    }

    // Frame the selection: the ball then spans much of the image's height, whole. (Edge pixels
    // average ball and background positions, so the framed bounds are loose: about half.)
    let covered = |port: u16| {
        let (_, png) = http(port, "GET", "/frame.png?channel=matte:CryptoObject", &own, None);
        let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut pixels).unwrap();
        // Covered pixels, and the rows they span.
        let rows: Vec<usize> =
            pixels.chunks(3).enumerate().filter(|(_, p)| p[0] == 255).map(|(i, _)| i / 160).collect();
        (rows.len(), rows.iter().max().unwrap_or(&0) - rows.iter().min().unwrap_or(&0))
    };
    let before = covered(view.port);
    let generation = wait_status(view.port, "the status", |_| true)["generation"].as_u64().unwrap();
    assert_eq!(http(view.port, "POST", "/camera/frame", &own, None).0, 204);
    wait_status(view.port, "the framed image", |s| {
        s["samples"] == 4 && s["generation"].as_u64() > Some(generation + 1)
    });
    let after = covered(view.port);
    assert!(after.0 > 2 * before.0, "framing grew the ball from {before:?} to {after:?} (pixels, rows)");
    assert!(after.1 >= 50 && after.1 < 119, "the ball spans much of the image's 120 rows, not all: {after:?}");
}

/// The value usd-core composes for `attribute` (`PATH.NAME`, or `PATH.NAME[i]` for a
/// component) with `layer` sublayered above `scene`; `None` (printed) where no Python with
/// usd-core is found outside CI. `STRATA_USD_PYTHON` names the interpreter (default `python3`).
fn usd_value(layer: &Path, scene: &Path, attribute: &str) -> Option<f64> {
    let python = std::env::var("STRATA_USD_PYTHON").unwrap_or_else(|_| "python3".into());
    let has_usd = Command::new(&python).args(["-c", "import pxr.Usd"]).output().is_ok_and(|o| o.status.success());
    if !has_usd {
        let reason = format!("{python} cannot import usd-core's pxr (set STRATA_USD_PYTHON)");
        assert!(std::env::var_os("CI").is_none(), "CI must install usd-core: {reason}");
        eprintln!("skipped the usd-core check: {reason}");
        return None;
    }
    let script = "import sys\nfrom pxr import Sdf, Usd\nlayer, scene, attr = sys.argv[1:]\n\
        written = Sdf.Layer.FindOrOpen(layer)\n\
        assert written.GetPrimAtPath('/Looks').specifier == Sdf.SpecifierOver\n\
        root = Sdf.Layer.CreateAnonymous('.usda')\nroot.subLayerPaths = [layer, scene]\n\
        path, _, index = attr.partition('[')\n\
        stage = Usd.Stage.Open(root)\n\
        value = stage.GetAttributeAtPath(path).Get()\n\
        print(value[int(index[:-1])] if index else value)\n";
    let out =
        Command::new(&python).args(["-c", script]).args([layer, scene]).arg(attribute).output().expect("python runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    Some(String::from_utf8_lossy(&out.stdout).trim().parse().expect("a number"))
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

// ---- tev ----------------------------------------------------------------------------------

/// A packet of tev's protocol as a test decodes it from the bytes (tev's `Ipc.h`: a u32
/// length including itself, a type byte, bools as a byte, NUL-terminated strings,
/// little-endian integers, f32 pixels).
#[derive(Debug)]
enum TevPacket {
    Create { name: String, width: i32, height: i32, channels: Vec<String> },
    Update { name: String, channels: Vec<String>, x: i32, y: i32, width: i32, height: i32, data: Vec<Vec<f32>> },
}

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take(&mut self, n: usize) -> &[u8] {
        let (head, rest) = self.0.split_at(n);
        self.0 = rest;
        head
    }
    fn byte(&mut self) -> u8 {
        self.take(1)[0]
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn i64(&mut self) -> i64 {
        i64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn text(&mut self) -> String {
        let end = self.0.iter().position(|&b| b == 0).expect("a NUL-terminated string");
        let s = String::from_utf8(self.take(end).to_vec()).unwrap();
        self.take(1);
        s
    }
}

fn decode_tev(packet: &[u8]) -> TevPacket {
    let mut r = Reader(packet);
    let length = u32::from_le_bytes(r.take(4).try_into().unwrap()) as usize;
    assert_eq!(length, packet.len());
    match r.byte() {
        4 => {
            assert_eq!(r.byte(), 1, "grab focus on create");
            let name = r.text();
            let (width, height, n) = (r.i32(), r.i32(), r.i32());
            let channels = (0..n).map(|_| r.text()).collect();
            assert!(r.0.is_empty(), "trailing bytes in CreateImage");
            TevPacket::Create { name, width, height, channels }
        }
        6 => {
            r.byte();
            let name = r.text();
            let n = r.i32() as usize;
            let channels: Vec<String> = (0..n).map(|_| r.text()).collect();
            let (x, y, width, height) = (r.i32(), r.i32(), r.i32(), r.i32());
            let offsets: Vec<i64> = (0..n).map(|_| r.i64()).collect();
            let strides: Vec<i64> = (0..n).map(|_| r.i64()).collect();
            let floats: Vec<f32> = r.0.chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
            let pixels = (width * height) as usize;
            let data = (0..n)
                .map(|c| (0..pixels).map(|p| floats[(offsets[c] + p as i64 * strides[c]) as usize]).collect())
                .collect();
            TevPacket::Update { name, channels, x, y, width, height, data }
        }
        other => panic!("unexpected packet type {other}"),
    }
}

/// A stand-in for tev: accepts one connection and collects its packets until it closes.
struct FakeTev {
    address: String,
    packets: std::sync::Arc<std::sync::Mutex<Vec<TevPacket>>>,
    thread: std::thread::JoinHandle<()>,
}

impl FakeTev {
    fn start() -> FakeTev {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap().to_string();
        let packets = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let sink = packets.clone();
        let thread = std::thread::spawn(move || {
            let (mut stream, _) = listener.accept().expect("a connection");
            let mut length = [0u8; 4];
            while stream.read_exact(&mut length).is_ok() {
                let mut packet = length.to_vec();
                packet.resize(u32::from_le_bytes(length) as usize, 0);
                stream.read_exact(&mut packet[4..]).expect("a whole packet");
                sink.lock().unwrap().push(decode_tev(&packet));
            }
        });
        FakeTev { address, packets, thread }
    }

    /// Rows received in updates so far.
    fn rows(&self) -> i32 {
        let packets = self.packets.lock().unwrap();
        packets.iter().map(|p| if let TevPacket::Update { height, .. } = p { *height } else { 0 }).sum()
    }

    fn finish(self) -> Vec<TevPacket> {
        self.thread.join().expect("the fake tev");
        std::mem::take(&mut *self.packets.lock().unwrap())
    }
}

/// The float channels of an EXR but Cryptomatte's, by name.
fn exr_channels(path: &Path) -> std::collections::BTreeMap<String, Vec<f32>> {
    let image = strata::render::film::output::read_exr(path).expect("the EXR reads back");
    let mut out = std::collections::BTreeMap::new();
    for c in &image.layer_data.channel_data.list {
        if let exr::image::FlatSamples::F32(v) = &c.sample_data
            && !c.name.to_string().starts_with("Crypto")
        {
            out.insert(c.name.to_string(), v.clone());
        }
    }
    out
}

/// Checks that `packets` create a `width`×`height` image with the EXR's float channels and
/// that the last update of each row holds the EXR's values, bit for bit.
fn assert_tev_shows(packets: &[TevPacket], exr: &Path, width: i32, height: i32) {
    let expected = exr_channels(exr);
    let TevPacket::Create { name: created, width: w, height: h, channels } = &packets[0] else {
        panic!("the first packet creates the image: {:?}", packets.first())
    };
    assert_eq!((*w, *h), (width, height));
    let mut names = channels.clone();
    names.sort();
    assert_eq!(names, expected.keys().cloned().collect::<Vec<_>>(), "tev gets the EXR's float channels");
    let mut shown: std::collections::BTreeMap<String, Vec<Option<f32>>> =
        channels.iter().map(|c| (c.clone(), vec![None; (width * height) as usize])).collect();
    for p in &packets[1..] {
        let TevPacket::Update { name, channels, x, y, width: uw, height: uh, data } = p else { panic!("{p:?}") };
        assert_eq!(name, created, "updates name the created image");
        assert_eq!((*x, *uw), (0, width), "updates are bands of whole rows");
        for (c, values) in channels.iter().zip(data) {
            let target = shown.get_mut(c).expect("a created channel");
            for (i, v) in values.iter().enumerate() {
                target[(*y * width) as usize + i] = Some(*v);
            }
            assert_eq!(values.len(), (uw * uh) as usize);
        }
    }
    for (name, values) in &expected {
        let got: Vec<f32> = shown[name].iter().map(|v| v.expect("every pixel sent")).collect();
        assert!(got.iter().zip(values).all(|(a, b)| a.to_bits() == b.to_bits()), "channel {name} differs");
    }
}

/// `render --display-server` sends the image it writes to tev: one CreateImage of the
/// right size and channels, then UpdateImage bands whose pixels are the EXR's bit for bit.
#[test]
fn render_sends_its_image_to_a_display_server() {
    let tev = FakeTev::start();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tev.exr");
    let status = Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["render", "--res", "24x16", "--spp", "2", "--display-server", &tev.address, "-o"])
        .arg(&out)
        .stdout(Stdio::null())
        .status()
        .expect("strata render runs");
    assert!(status.success());
    let packets = tev.finish();
    assert!(matches!(&packets[0], TevPacket::Create { name, .. } if name == "tev.exr"), "{:?}", packets.first());
    assert_tev_shows(&packets, &out, 24, 16);
}

/// `view --display-server` streams every full-resolution pass; the last one is `render`'s
/// image at the same settings.
#[test]
fn the_view_streams_its_passes_to_a_display_server() {
    let tev = FakeTev::start();
    let (dir, scene) = scene_dir();
    let view = View::start(&scene, &["--display-server", &tev.address]);
    // Passes of 1, 2 and 4 samples: three full images of 120 rows.
    let deadline = Instant::now() + Duration::from_secs(180);
    while tev.rows() < 3 * 120 {
        assert!(Instant::now() < deadline, "the view sent {} rows", tev.rows());
        std::thread::sleep(Duration::from_millis(20));
    }
    drop(view);
    let packets = tev.finish();
    let out = dir.path().join("render.exr");
    let status = Command::new(env!("CARGO_BIN_EXE_strata"))
        .arg("render")
        .arg(&scene)
        .args(["--res", "160x120", "--spp", "4", "-o"])
        .arg(&out)
        .stdout(Stdio::null())
        .status()
        .expect("strata render runs");
    assert!(status.success());
    assert_tev_shows(&packets, &out, 160, 120);
}

/// A ball with three layers: a base, a layer whose mask input is 0 and, on top, one whose mask
/// input is 0.3 (both masks are live inputs: evaluated per hit, not known when compiling).
fn three_layer_ball(dir: &Path) -> PathBuf {
    std::fs::write(
        dir.join("layers.ash"),
        "substance base { node d = diffuse(albedo: color(0.5, 0.5, 0.5)); surface = d.bsdf; }\n\
         substance film {\n    input float coverage = 1.0;\n    node m = mask(opacity: coverage);\n    \
         node d = diffuse(albedo: color(0.9, 0.1, 0.1));\n    surface = d.bsdf;\n    mask = m.out;\n}\n",
    )
    .unwrap();
    let material = |name: &str, graph: &str, coverage: &str| {
        format!(
            "    def Material \"{name}\"\n    {{\n        def Shader \"Surface\"\n        {{\n            \
             uniform token info:implementationSource = \"sourceAsset\"\n            \
             uniform asset info:strata:sourceAsset = @layers.ash@\n            \
             uniform token info:strata:sourceAsset:subIdentifier = \"{graph}\"\n{coverage}        }}\n    }}\n"
        )
    };
    let scene = dir.join("ball.usda");
    std::fs::write(
        &scene,
        format!(
            "#usda 1.0\n(\n    upAxis = \"Y\"\n)\n\ndef Sphere \"Ball\"\n{{\n    double radius = 1\n    \
             rel material:slotBinding:_000 = </Looks/Base>\n    rel material:slotBinding:_050 = </Looks/Hidden>\n    \
             rel material:slotBinding:_060 = </Looks/Film>\n}}\n\ndef Scope \"Looks\"\n{{\n{}{}{}}}\n",
            material("Base", "base", ""),
            material("Hidden", "film", "            float inputs:coverage = 0\n"),
            material("Film", "film", "            float inputs:coverage = 0.3\n"),
        ),
    )
    .unwrap();
    scene
}

/// Per-layer coverage mattes of the selected prim: every layer of its stack has one in the
/// channel list; inside the ball they sum to its coverage (1; the Cryptomatte matte of the
/// render's own samples is the independent reference), the layer with mask 0 reads 0, the one
/// with the constant mask 0.3 reads 0.3 and the base the rest, 0.7 (each within the PNG's
/// 8-bit rounding), and outside the ball all read 0.
#[test]
fn per_layer_coverage_mattes_sum_to_the_prims_coverage_and_follow_the_masks() {
    let dir = tempfile::tempdir().unwrap();
    let scene = three_layer_ball(dir.path());
    let view = View::start(&scene, &[]);
    let own = format!("127.0.0.1:{}", view.port);
    wait_status(view.port, "the converged image", |s| s["samples"] == 4);
    let (_, body) = http(view.port, "GET", "/pick?x=80&y=60", &own, None);
    let pick: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(pick["prim"], "/Ball", "{pick}");
    let status = wait_status(view.port, "the selection", |s| s["selected"] == "/Ball");
    let channels: Vec<&str> = status["channels"].as_array().unwrap().iter().filter_map(|c| c.as_str()).collect();
    let coverage: Vec<&str> = channels.iter().copied().filter(|c| c.starts_with("coverage:")).collect();
    assert_eq!(coverage, ["coverage:0:000", "coverage:1:050", "coverage:2:060"], "{status}");
    let grey = |channel: &str| -> Vec<f32> {
        let (code, png) = http(view.port, "GET", &format!("/frame.png?channel={channel}"), &own, None);
        assert_eq!(code, 200, "{channel}");
        let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut pixels).unwrap();
        pixels.chunks(3).map(|p| f32::from(p[0]) / 255.0).collect()
    };
    let mattes: Vec<Vec<f32>> = coverage.iter().map(|c| grey(c)).collect();
    let object = grey("matte:CryptoObject");
    let (width, height) = (160, 120);
    // Pixels whose whole 3x3 neighbourhood the render's samples find fully inside or outside.
    let settled = |x: usize, y: usize, value: f32| {
        (y.saturating_sub(1)..=(y + 1).min(height - 1))
            .all(|j| (x.saturating_sub(1)..=(x + 1).min(width - 1)).all(|i| object[j * width + i] == value))
    };
    let rounding = 1.0 / 255.0;
    let (mut inside, mut outside) = (0, 0);
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let at: Vec<f32> = mattes.iter().map(|m| m[i]).collect();
            if settled(x, y, 1.0) {
                inside += 1;
                let sum: f32 = at.iter().sum();
                assert!((sum - 1.0).abs() <= 2.0 * rounding, "({x}, {y}): mattes {at:?} sum to {sum}");
                assert_eq!(at[1], 0.0, "({x}, {y}): mask 0 → matte 0");
                assert!((at[2] - 0.3).abs() <= rounding, "({x}, {y}): mask 0.3 → matte {}", at[2]);
                assert!((at[0] - 0.7).abs() <= rounding, "({x}, {y}): the base takes the rest: {}", at[0]);
            } else if settled(x, y, 0.0) {
                outside += 1;
                assert!(at.iter().all(|&m| m == 0.0), "({x}, {y}): outside the ball {at:?}");
            }
        }
    }
    assert!(inside > 1000 && outside > 1000, "the ball and the background are both seen: {inside}, {outside}");
}
