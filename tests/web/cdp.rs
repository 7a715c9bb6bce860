//! A headless Chromium driven over the DevTools protocol on a pipe
//! (`--remote-debugging-pipe`: the browser reads commands on fd 3 and writes
//! answers and events on fd 4, each message JSON ended by a NUL byte).
//! The browser is Debian's `chromium` (`MESHSMOOTH_CHROMIUM` overrides the
//! path); nothing is downloaded.

use base64::Engine;
use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::{Duration, Instant};

/// How long one protocol command may take (a slow CI machine renders in
/// software).
const COMMAND_TIMEOUT: Duration = Duration::from_secs(60);

/// A running browser with one page attached; killed on drop.
pub struct Browser {
    child: Child,
    commands: ChildStdin,
    messages: Receiver<Value>,
    next_id: u64,
    session: String,
    /// Every event received so far, in order.
    pub events: Vec<Value>,
    profile: PathBuf,
}

/// The browser binary: `MESHSMOOTH_CHROMIUM` or `chromium` on the PATH.
fn chromium() -> String {
    std::env::var("MESHSMOOTH_CHROMIUM").unwrap_or_else(|_| "chromium".to_owned())
}

impl Browser {
    /// Starts headless Chromium with a fresh profile under `dir` and opens
    /// an empty page; its log goes to `dir/chromium.log`.
    pub fn launch(dir: &Path) -> Browser {
        let profile = dir.join("profile");
        let _ = std::fs::remove_dir_all(&profile);
        std::fs::create_dir_all(&profile).expect("create the browser profile");
        let log = std::fs::File::create(dir.join("chromium.log")).expect("create chromium.log");
        // The shell moves our pipes to fds 3 and 4, then runs the browser.
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(r#"exec "$0" "$@" 3<&0 4>&1 0</dev/null 1>&2"#)
            .arg(chromium())
            .args([
                "--headless",
                "--no-sandbox", // tests run as root in CI containers
                "--remote-debugging-pipe",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-extensions",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--metrics-recording-only",
                "--window-size=1280,1800",
                "--hide-scrollbars",
                "--mute-audio",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| {
                panic!(
                    "cannot start `{}` ({e}): install Debian's chromium \
                     (`apt-get install -y chromium`; .ci/run does)",
                    chromium()
                )
            });
        let commands = child.stdin.take().expect("browser fd 3");
        let answers = child.stdout.take().expect("browser fd 4");
        let (tx, messages) = channel();
        std::thread::spawn(move || {
            let mut reader = BufReader::new(answers);
            let mut buf = Vec::new();
            while let Ok(n) = reader.read_until(0, &mut buf) {
                if n == 0 {
                    break;
                }
                if buf.last() == Some(&0) {
                    buf.pop();
                }
                if let Ok(v) = serde_json::from_slice::<Value>(&buf)
                    && tx.send(v).is_err()
                {
                    break;
                }
                buf.clear();
            }
        });
        let mut browser = Browser {
            child,
            commands,
            messages,
            next_id: 0,
            session: String::new(),
            events: Vec::new(),
            profile,
        };
        let target = browser.browser_call("Target.createTarget", json!({"url": "about:blank"}));
        let target = target["targetId"].as_str().expect("targetId").to_owned();
        let attached = browser.browser_call(
            "Target.attachToTarget",
            json!({"targetId": target, "flatten": true}),
        );
        browser.session = attached["sessionId"]
            .as_str()
            .expect("sessionId")
            .to_owned();
        for domain in ["Page.enable", "Runtime.enable", "Log.enable"] {
            browser.call(domain, json!({}));
        }
        browser
    }

    fn send(&mut self, method: &str, params: Value, session: bool) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let mut message = json!({"id": id, "method": method, "params": params});
        if session {
            message["sessionId"] = json!(self.session);
        }
        let mut bytes = serde_json::to_vec(&message).expect("encode");
        bytes.push(0);
        self.commands
            .write_all(&bytes)
            .and_then(|()| self.commands.flush())
            .unwrap_or_else(|e| panic!("{method}: the browser went away ({e})"));
        let deadline = Instant::now() + COMMAND_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.messages.recv_timeout(left) {
                Ok(m) if m["id"] == id => {
                    if let Some(e) = m.get("error") {
                        panic!("{method} failed: {e}");
                    }
                    return m["result"].clone();
                }
                Ok(m) => self.events.push(m),
                Err(RecvTimeoutError::Timeout) => panic!("{method}: no answer in {left:?}"),
                Err(RecvTimeoutError::Disconnected) => panic!("{method}: the browser exited"),
            }
        }
    }

    /// A command to the browser itself.
    pub fn browser_call(&mut self, method: &str, params: Value) -> Value {
        self.send(method, params, false)
    }

    /// A command to the page.
    pub fn call(&mut self, method: &str, params: Value) -> Value {
        self.send(method, params, true)
    }

    /// Collects the events that arrived without waiting.
    pub fn drain(&mut self) {
        while let Ok(m) = self.messages.try_recv() {
            self.events.push(m);
        }
    }

    /// Navigates to `url`.
    pub fn open(&mut self, url: &str) {
        let r = self.call("Page.navigate", json!({"url": url}));
        assert!(r.get("errorText").is_none(), "navigate to {url}: {r}");
    }

    /// Evaluates `expression` in the page (promises awaited): its value,
    /// or the exception it threw.
    pub fn try_eval(&mut self, expression: &str) -> Result<Value, Value> {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true, "awaitPromise": true}),
        );
        match r.get("exceptionDetails") {
            Some(e) => Err(e.clone()),
            None => Ok(r["result"]["value"].clone()),
        }
    }

    /// [`Browser::try_eval`], panicking on an exception.
    pub fn eval(&mut self, expression: &str) -> Value {
        self.try_eval(expression)
            .unwrap_or_else(|e| panic!("`{expression}` threw: {e}"))
    }

    /// Polls `expression` until it is true (an exception counts as not
    /// yet: the page may be loading); panics with `describe`'s value after
    /// `timeout`.
    pub fn wait_for(&mut self, expression: &str, timeout: Duration, describe: &str) {
        let start = Instant::now();
        loop {
            let value = self.try_eval(expression);
            if value == Ok(json!(true)) {
                return;
            }
            if start.elapsed() > timeout {
                panic!(
                    "`{expression}` not true after {timeout:?} ({value:?}): {:?}",
                    self.try_eval(describe)
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Sets the files of the `<input type=file>` matched by `selector`
    /// (fires its change event).
    pub fn set_file(&mut self, selector: &str, file: &Path) {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": format!("document.querySelector({selector:?})")}),
        );
        let object = r["result"]["objectId"]
            .as_str()
            .unwrap_or_else(|| panic!("no element {selector}: {r}"))
            .to_owned();
        self.call(
            "DOM.setFileInputFiles",
            json!({"files": [file.display().to_string()], "objectId": object}),
        );
    }

    /// Clicks the link matched by `selector` and waits for the download it
    /// starts; returns the downloaded file (in `dir`).
    pub fn download(&mut self, selector: &str, dir: &Path) -> PathBuf {
        std::fs::create_dir_all(dir).expect("create the download folder");
        self.browser_call(
            "Browser.setDownloadBehavior",
            json!({"behavior": "allowAndName", "downloadPath": dir.display().to_string(),
                   "eventsEnabled": true}),
        );
        let first = self.events.len();
        self.eval(&format!(
            "document.querySelector({selector:?}).click(), true"
        ));
        let start = Instant::now();
        loop {
            self.drain();
            let done = self.events[first..].iter().find_map(|e| {
                (e["method"] == "Browser.downloadProgress")
                    .then(|| &e["params"])
                    .filter(|p| p["state"] != "inProgress")
                    .cloned()
            });
            if let Some(p) = done {
                assert_eq!(p["state"], "completed", "download {p}");
                let guid = p["guid"].as_str().expect("download guid");
                return dir.join(guid);
            }
            assert!(
                start.elapsed() < COMMAND_TIMEOUT,
                "no download from {selector}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// A PNG of the whole page, written to `path`.
    pub fn screenshot(&mut self, path: &Path) {
        let r = self.call(
            "Page.captureScreenshot",
            json!({"format": "png", "captureBeyondViewport": true}),
        );
        let png = base64::engine::general_purpose::STANDARD
            .decode(r["data"].as_str().expect("screenshot data"))
            .expect("screenshot base64");
        std::fs::write(path, png).expect("write the screenshot");
    }

    /// Console errors, uncaught exceptions and error log entries so far,
    /// as text (network entries whose text contains one of `expected` are
    /// left out: a refused upload logs its status).
    pub fn errors(&mut self, expected: &[&str]) -> Vec<String> {
        self.drain();
        let mut errors = Vec::new();
        for e in &self.events {
            let p = &e["params"];
            match e["method"].as_str() {
                Some("Runtime.consoleAPICalled")
                    if p["type"] == "error" || p["type"] == "assert" =>
                {
                    errors.push(format!("console.{}: {}", p["type"], p["args"]));
                }
                Some("Runtime.exceptionThrown") => {
                    errors.push(format!("exception: {}", p["exceptionDetails"]));
                }
                Some("Log.entryAdded") if p["entry"]["level"] == "error" => {
                    let text = p["entry"]["text"].as_str().unwrap_or_default();
                    let url = p["entry"]["url"].as_str().unwrap_or_default();
                    if !expected.iter().any(|x| text.contains(x) || url.contains(x)) {
                        errors.push(format!("log: {text} ({url})"));
                    }
                }
                _ => {}
            }
        }
        errors
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        // Ask the browser to close, so its helper processes end with it;
        // kill it if it does not within a few seconds.
        let close = json!({"id": 0, "method": "Browser.close"}).to_string() + "\0";
        let _ = self.commands.write_all(close.as_bytes());
        let _ = self.commands.flush();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}
