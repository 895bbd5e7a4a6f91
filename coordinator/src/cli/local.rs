//! Worker processes started on loopback for one command.

use anyhow::Context;

/// Worker processes started for one render, stopped when dropped.
pub struct LocalWorkers {
    children: Vec<std::process::Child>,
    /// Their addresses.
    pub addrs: Vec<String>,
}

impl LocalWorkers {
    /// Starts `n` workers on loopback that require `token`.
    pub fn start(n: usize, token: &str) -> anyhow::Result<Self> {
        use std::io::BufRead;
        let exe = std::env::current_exe().context("cannot find the sylva executable")?;
        let mut w = LocalWorkers { children: Vec::new(), addrs: Vec::new() };
        for _ in 0..n {
            let mut child = std::process::Command::new(&exe)
                .args(["worker", "--listen", "127.0.0.1:0"])
                .env("SYLVA_TOKEN", token)
                .stdout(std::process::Stdio::piped())
                .spawn()
                .context("cannot start a local worker")?;
            let mut line = String::new();
            std::io::BufReader::new(child.stdout.take().expect("piped")).read_line(&mut line)?;
            w.children.push(child);
            let addr = line.trim().strip_prefix("sylva worker listening on ").context("a local worker did not start")?;
            w.addrs.push(addr.to_string());
        }
        Ok(w)
    }
}

impl Drop for LocalWorkers {
    fn drop(&mut self) {
        for c in &mut self.children {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}


/// A fresh random token for workers only this process talks to.
pub fn fresh_token() -> String {
    sylva_shared::bundle::hash_of(format!("{:?} {}", std::time::SystemTime::now(), std::process::id()).as_bytes())
}
