//! Worker and coordinator processes started on loopback for one command.

use anyhow::Context;
use std::process::Child;

/// Starts `sylva ARGS` with `token` required, and reads the address it
/// announces on its first line (`sylva … listening on ADDR`).
fn spawn_announcing(args: &[String], token: &str) -> anyhow::Result<(Child, String)> {
    use std::io::BufRead;
    let exe = std::env::current_exe().context("cannot find the sylva executable")?;
    let mut child = std::process::Command::new(&exe)
        .args(args)
        .env("SYLVA_TOKEN", token)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .with_context(|| format!("cannot start a local `sylva {}`", args[0]))?;
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().expect("piped")).read_line(&mut line)?;
    match line.trim().split_once(" listening on ") {
        Some((_, addr)) => Ok((child, addr.to_string())),
        None => {
            let _ = child.kill();
            let _ = child.wait();
            anyhow::bail!("a local `sylva {}` did not start (see its error above)", args[0])
        }
    }
}

/// Processes started for one command, stopped when dropped.
#[derive(Default)]
pub struct LoopbackProcesses {
    children: Vec<Child>,
}

impl LoopbackProcesses {
    /// Starts `n` workers on loopback that require `token`; returns their addresses.
    pub fn start_workers(&mut self, n: usize, token: &str) -> anyhow::Result<Vec<String>> {
        self.start_workers_with(n, token, &[])
    }

    /// [`LoopbackProcesses::start_workers`] with more worker flags.
    pub fn start_workers_with(
        &mut self,
        n: usize,
        token: &str,
        extra: &[String],
    ) -> anyhow::Result<Vec<String>> {
        let mut addrs = Vec::new();
        for _ in 0..n {
            let mut args: Vec<String> =
                ["worker", "--listen", "127.0.0.1:0"].map(String::from).to_vec();
            args.extend_from_slice(extra);
            let (child, addr) = spawn_announcing(&args, token)?;
            self.children.push(child);
            addrs.push(addr);
        }
        Ok(addrs)
    }

    /// Starts a coordinator on loopback over `workers`, requiring `token`
    /// from clients and sending it to workers; `extra` are more of its flags.
    pub fn start_coordinator(
        &mut self,
        workers: &[String],
        token: &str,
        extra: &[String],
    ) -> anyhow::Result<String> {
        let mut args: Vec<String> =
            ["coordinator", "--listen", "127.0.0.1:0", "--max-running", "1", "--ephemeral"]
                .map(String::from)
                .to_vec();
        if !workers.is_empty() {
            args.extend(["--workers".to_string(), workers.join(",")]);
        }
        args.extend_from_slice(extra);
        let (child, addr) = spawn_announcing(&args, token)?;
        self.children.push(child);
        Ok(addr)
    }
}

impl Drop for LoopbackProcesses {
    fn drop(&mut self) {
        // SIGTERM first, so each cleans up its temporary folders; a child
        // that has not left after two seconds is killed.
        #[cfg(unix)]
        for c in &self.children {
            // SAFETY: signals our own child process.
            unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
        }
        let until = std::time::Instant::now() + std::time::Duration::from_secs(2);
        for c in &mut self.children {
            while std::time::Instant::now() < until && c.try_wait().ok().flatten().is_none() {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
