//! The farm from the command line, beside `submit`: `jobs`, `workers`,
//! `cancel`, `requeue`, `priority` and `fetch` (as OpenCue's `cueman` and Flamenco's
//! CLI offer). Tables for people, `--json` for scripts.

use crate::flags::jobs::*;
use anyhow::Context;
use serde::Serialize;
use sylva_coordinator::client::status_error;
use sylva_coordinator::job_state::wire_name;
use sylva_proto::pb;

/// A job as listings show it (the wire summary, times as seconds).
#[derive(Serialize)]
struct JobRow {
    id: String,
    name: String,
    state: String,
    priority: i32,
    strips_done: u32,
    strips_total: u32,
    /// Frames (1 unless a sequence) and frames finished.
    frames: u32,
    frames_done: u32,
    retries: u32,
    submitter: String,
    submitted_unix_ms: u64,
    started_unix_ms: Option<u64>,
    finished_unix_ms: Option<u64>,
    /// Seconds queued, then running (up to now while it runs).
    queued_s: Option<f64>,
    running_s: Option<f64>,
    /// What the farm is doing for it now (empty once ended).
    stage: String,
    /// Seconds left, estimated from the strips returned since the first.
    eta_s: Option<f64>,
    error: Option<String>,
}

impl JobRow {
    fn of(j: pb::JobSummary, now_ms: u64) -> Self {
        let nz = |v: u64| (v > 0).then_some(v);
        let (sub, start, end) =
            (j.submitted_unix_ms, nz(j.started_unix_ms), nz(j.finished_unix_ms));
        let secs = |a: u64, b: u64| b.saturating_sub(a) as f64 / 1e3;
        Self {
            queued_s: (sub > 0).then(|| secs(sub, start.or(end).unwrap_or(now_ms))),
            running_s: start.map(|s| secs(s, end.unwrap_or(now_ms))),
            id: j.id,
            name: j.name,
            state: wire_name(j.state).to_string(),
            priority: j.priority,
            strips_done: j.strips_done,
            strips_total: j.strips_total,
            frames: j.frames.max(1),
            frames_done: j.frames_done,
            retries: j.retries,
            submitter: j.submitter,
            submitted_unix_ms: sub,
            started_unix_ms: start,
            finished_unix_ms: end,
            stage: j.stage,
            eta_s: (j.eta_ms > 0).then(|| j.eta_ms as f64 / 1e3),
            error: Some(j.error).filter(|e| !e.is_empty()),
        }
    }
}

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// `s` as it may reach a terminal: the characters the coordinator refuses
/// in names (control, bidirectional formatting) written as `\u{…}`, since
/// a worker's error text or an older coordinator's job name may hold them.
use sylva_scene::sandbox::escaped;
use unicode_width::{UnicodeWidthChar, UnicodeWidthStr};

/// Left-aligned columns, two spaces apart, the header first; every cell
/// [`escaped`].
pub(crate) fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let rows: Vec<Vec<String>> =
        rows.iter().map(|r| r.iter().map(|c| escaped(c)).collect()).collect();
    let rows = &rows;
    // Columns on a terminal: a CJK character or an emoji takes two.
    let mut width: Vec<usize> = header.iter().map(|h| h.width()).collect();
    for r in rows {
        for (w, c) in width.iter_mut().zip(r) {
            *w = (*w).max(c.width());
        }
    }
    let line = |cells: Vec<String>| {
        let mut s: String = cells
            .iter()
            .zip(&width)
            .map(|(c, w)| format!("{c}{}  ", " ".repeat(w - c.width())))
            .collect();
        s.truncate(s.trim_end().len());
        s + "\n"
    };
    std::iter::once(line(header.iter().map(|h| h.to_string()).collect()))
        .chain(rows.iter().map(|r| line(r.clone())))
        .collect()
}

fn seconds(s: Option<f64>) -> String {
    s.map(|s| format!("{s:.1}s")).unwrap_or_else(|| "-".into())
}

/// The width a listing keeps to unless asked for all of it (`--wide`).
const COLUMNS: usize = 80;

/// Every column of every job, as wide as they come (`sylva jobs --wide`).
fn wide_job_table(rows: &[JobRow]) -> String {
    let cells: Vec<Vec<String>> = rows
        .iter()
        .map(|j| {
            vec![
                j.id.clone(),
                j.state.clone(),
                j.priority.to_string(),
                format!("{}/{}", j.strips_done, j.strips_total),
                format!("{}/{}", j.frames_done, j.frames),
                j.retries.to_string(),
                seconds(j.queued_s),
                seconds(j.running_s),
                seconds(j.eta_s),
                j.stage.clone(),
                j.submitter.clone(),
                j.name.clone(),
                j.error.clone().unwrap_or_default(),
            ]
        })
        .collect();
    table(
        &[
            "ID",
            "STATE",
            "PRIO",
            "STRIPS",
            "FRAMES",
            "RETRIES",
            "QUEUED",
            "RUNNING",
            "LEFT",
            "STAGE",
            "SUBMITTER",
            "NAME",
            "ERROR",
        ],
        &cells,
    )
}

/// The jobs in [`COLUMNS`] columns: one line each (strips done, and
/// frames for a sequence; the time in its state: queued, then running;
/// the time left), and under a running job its stage, under a failed or
/// cancelled one its error, indented. A line too long is cut (`…`).
fn job_table(rows: &[JobRow]) -> String {
    let cells: Vec<Vec<String>> = rows
        .iter()
        .map(|j| {
            let frames = if j.frames > 1 {
                format!(" f{}/{}", j.frames_done, j.frames)
            } else {
                String::new()
            };
            vec![
                j.id.clone(),
                j.state.clone(),
                j.priority.to_string(),
                format!("{}/{}{frames}", j.strips_done, j.strips_total),
                seconds(j.running_s.or(j.queued_s)),
                seconds(j.eta_s),
                j.submitter.clone(),
                j.name.clone(),
            ]
        })
        .collect();
    let header = ["ID", "STATE", "PRIO", "DONE", "TIME", "LEFT", "SUBMITTER", "NAME"];
    let lines = table(&header, &cells);
    let mut lines = lines.lines().map(|l| fit(l, COLUMNS));
    let mut out = lines.next().unwrap_or_default() + "\n";
    for (j, line) in rows.iter().zip(lines) {
        out += &line;
        out.push('\n');
        let note = j.error.as_deref().unwrap_or(&j.stage);
        if !note.is_empty() {
            out += &fit(&format!("  {}", escaped(note)), COLUMNS);
            out.push('\n');
        }
    }
    out
}

/// `line` cut to `width` terminal columns, an ellipsis marking the cut.
fn fit(line: &str, width: usize) -> String {
    if line.width() <= width {
        return line.to_string();
    }
    let mut out = String::new();
    let mut used = 0;
    for c in line.chars() {
        let w = c.width().unwrap_or(0);
        if used + w > width.saturating_sub(1) {
            break;
        }
        out.push(c);
        used += w;
    }
    out + "…"
}

/// Runs `sylva jobs`.
pub fn run_jobs(a: JobsArgs) -> anyhow::Result<()> {
    let reply = a.at.call(async |mut c| {
        Ok(c.list_jobs(pb::ListJobsRequest {}).await.map_err(status_error)?.into_inner())
    })?;
    if !reply.store_problem.is_empty() {
        eprintln!("warning: {}", reply.store_problem);
    }
    let list = reply.jobs;
    let now = now_ms();
    let mut rows: Vec<JobRow> = list
        .into_iter()
        .map(|j| JobRow::of(j, now))
        .filter(|j| a.state.is_none_or(|s| j.state == s.name()))
        .collect();
    rows.sort_by_key(|j| j.submitted_unix_ms);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else if a.wide {
        print!("{}", wide_job_table(&rows));
    } else {
        print!("{}", job_table(&rows));
    }
    Ok(())
}

/// A worker as listings show it.
#[derive(Serialize)]
struct WorkerRow {
    addr: String,
    alive: bool,
    adapter: String,
    /// Whether the adapter offers ray queries.
    ray_queries: bool,
    /// The traversal its latest preparation chose, and why.
    backend: String,
    backend_why: String,
    gpu_memory_bytes: u64,
    busy_strips: u32,
    strips_done: u64,
    strips_failed: u64,
    cached_scenes: Vec<String>,
}

/// Runs `sylva workers`.
pub fn run_workers(a: WorkersArgs) -> anyhow::Result<()> {
    let list = a.at.call(async |mut c| {
        Ok(c.list_workers(pb::ListWorkersRequest {})
            .await
            .map_err(status_error)?
            .into_inner()
            .workers)
    })?;
    let mut rows: Vec<WorkerRow> = list
        .into_iter()
        .map(|w| WorkerRow {
            addr: w.addr,
            alive: w.alive,
            adapter: w.adapter,
            ray_queries: w.ray_queries,
            backend: w.backend,
            backend_why: w.backend_why,
            gpu_memory_bytes: w.gpu_memory_bytes,
            busy_strips: w.busy_strips,
            strips_done: w.strips_done,
            strips_failed: w.strips_failed,
            cached_scenes: w.cached_scenes,
        })
        .collect();
    rows.sort_by(|a, b| a.addr.cmp(&b.addr));
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    let cells: Vec<Vec<String>> = rows
        .iter()
        .map(|w| {
            vec![
                w.addr.clone(),
                if w.alive { "yes" } else { "no" }.into(),
                w.adapter.clone(),
                // The choice, and whether ray queries were there to choose.
                format!(
                    "{}{}",
                    if w.backend.is_empty() { "–" } else { &w.backend },
                    if w.ray_queries { " (rq offered)" } else { "" }
                ),
                w.busy_strips.to_string(),
                w.strips_done.to_string(),
                w.strips_failed.to_string(),
                // A bundle hash's first 12 digits name it well enough in a table.
                w.cached_scenes
                    .iter()
                    .map(|h| h.chars().take(12).collect::<String>())
                    .collect::<Vec<_>>()
                    .join(","),
            ]
        })
        .collect();
    print!(
        "{}",
        table(
            &["ADDR", "ALIVE", "ADAPTER", "TRAVERSAL", "BUSY", "DONE", "FAILED", "CACHED"],
            &cells
        )
    );
    Ok(())
}

/// Runs `sylva cancel`: every id is tried; the command fails if any was not found.
pub fn run_cancel(a: JobIdsArgs) -> anyhow::Result<()> {
    let results = a.at.call(async |mut c| {
        let mut out = Vec::new();
        for id in &a.ids {
            out.push(
                c.cancel_job(pb::JobId { id: id.clone() })
                    .await
                    .map(|r| r.into_inner())
                    .map_err(status_error),
            );
        }
        Ok(out)
    })?;
    let now = now_ms();
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    for (id, r) in a.ids.iter().zip(results) {
        match r {
            // A job that had ended before is not cancelled: say so.
            Ok(s) if s.state != pb::JobState::Cancelled as i32 => {
                failed.push(format!("{id} is {}: nothing to cancel", wire_name(s.state)))
            }
            Ok(s) => rows.push(JobRow::of(s, now)),
            Err(e) => failed.push(format!("{id}: {e}")),
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        for j in &rows {
            println!("{} {}", j.id, j.state);
        }
    }
    anyhow::ensure!(failed.is_empty(), "{}", failed.join("; "));
    Ok(())
}

/// Runs `sylva requeue`: each job's new id, or why it was not requeued.
pub fn run_requeue(a: JobIdsArgs) -> anyhow::Result<()> {
    let results = a.at.call(async |mut c| {
        let mut out = Vec::new();
        for id in &a.ids {
            let r = c.requeue_job(pb::JobId { id: id.clone() }).await;
            out.push(r.map(|r| r.into_inner().id).map_err(status_error));
        }
        Ok(out)
    })?;
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    for (id, r) in a.ids.iter().zip(results) {
        match r {
            Ok(new) => rows.push(serde_json::json!({ "id": id, "requeued_as": new })),
            Err(e) => failed.push(format!("{id}: {e}")),
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        for r in &rows {
            println!(
                "{} requeued as {}",
                r["id"].as_str().unwrap_or(""),
                r["requeued_as"].as_str().unwrap_or("")
            );
        }
    }
    anyhow::ensure!(failed.is_empty(), "{}", failed.join("; "));
    Ok(())
}

/// Runs `sylva priority`.
pub fn run_priority(a: PriorityArgs) -> anyhow::Result<()> {
    let s = a.at.call(async |mut c| {
        Ok(c.set_priority(pb::SetPriorityRequest { id: a.id.clone(), priority: a.priority })
            .await
            .map_err(status_error)?
            .into_inner())
    })?;
    let row = JobRow::of(s, now_ms());
    if a.json {
        println!("{}", serde_json::to_string_pretty(&row)?);
    } else {
        println!("{} {} priority {}", row.id, row.state, row.priority);
    }
    Ok(())
}

/// Runs `sylva fetch`.
pub fn run_fetch(a: FetchArgs) -> anyhow::Result<()> {
    let exr = a.out.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    let format = if exr { "exr" } else { "png" };
    if a.all {
        anyhow::ensure!(
            !exr,
            "--all writes PNG frames (and their sheet and preview); fetch EXR frames one by one with --frame"
        );
        let pngs = a.at.call(async |mut c| {
            let jobs =
                c.list_jobs(pb::ListJobsRequest {}).await.map_err(status_error)?.into_inner().jobs;
            let frames = jobs
                .iter()
                .find(|j| j.id == a.id)
                .map(|j| j.frames.max(1))
                .with_context(|| format!("no job {}", a.id))?;
            let mut pngs = Vec::new();
            for frame in 0..frames {
                pngs.push(
                    c.fetch_result(pb::FetchRequest {
                        id: a.id.clone(),
                        format: "png".into(),
                        frame,
                    })
                    .await
                    .map_err(status_error)?
                    .into_inner()
                    .data,
                );
            }
            Ok(pngs)
        })?;
        let written = sylva_coordinator::sequence::write_all(&a.out, &pngs, None)?;
        println!(
            "{}: wrote {} frames, {} and {}",
            a.id,
            pngs.len(),
            written[written.len() - 2].display(),
            written[written.len() - 1].display()
        );
        return Ok(());
    }
    let data = a.at.call(async |mut c| {
        Ok(c.fetch_result(pb::FetchRequest {
            id: a.id.clone(),
            format: format.into(),
            frame: a.frame,
        })
        .await
        .map_err(status_error)?
        .into_inner()
        .data)
    })?;
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&a.out, &data).with_context(|| format!("{}: cannot write", a.out.display()))?;
    println!("{}: wrote {} ({} bytes)", a.id, a.out.display(), data.len());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_table_lines_up_its_columns() {
        let t = table(
            &["ID", "STATE"],
            &[vec!["job-1".into(), "done".into()], vec!["j".into(), "queued".into()]],
        );
        assert_eq!(t, "ID     STATE\njob-1  done\nj      queued\n");
    }

    #[test]
    fn text_from_outside_cannot_drive_the_terminal() {
        // A worker's error that would retitle and clear the terminal, then
        // forge a row; a name turned around by a right-to-left override.
        let t = table(
            &["ID", "ERROR"],
            &[vec!["job-1".into(), "ok\u{1b}]0;T\u{7}\u{1b}[2J\r\njob-2  done".into()]],
        );
        assert!(!t.chars().any(|c| c.is_control() && c != '\n'), "{t:?}");
        assert_eq!(t.lines().count(), 2, "{t}");
        assert!(t.contains("ok\\u{1b}]0;T\\u{7}\\u{1b}[2J\\u{d}\\u{a}job-2"), "{t}");
        assert_eq!(escaped("exe.\u{202e}gpj"), "exe.\\u{202e}gpj");
    }

    #[test]
    fn the_listing_keeps_to_80_columns_and_says_each_jobs_stage_or_error() {
        let long = "a name much longer than any column could hold, and then some more";
        let running = pb::JobSummary {
            id: "job-3fa2c1-12".into(),
            state: pb::JobState::Running as i32,
            name: long.into(),
            submitter: "alice@192.168.100.200".into(),
            strips_done: 40,
            strips_total: 120,
            frames: 24,
            frames_done: 7,
            submitted_unix_ms: 1_000,
            started_unix_ms: 2_000,
            eta_ms: 12_500,
            stage: format!("127.0.0.1:50151 preparing the scene: {long}"),
            ..Default::default()
        };
        let failed = pb::JobSummary {
            id: "job-3fa2c1-13".into(),
            state: pb::JobState::Failed as i32,
            error: format!("no worker could render strip 3: {long}"),
            ..Default::default()
        };
        let rows = [JobRow::of(running, 10_000), JobRow::of(failed, 10_000)];
        let t = job_table(&rows);
        for line in t.lines() {
            assert!(line.width() <= COLUMNS, "{} columns: {line}", line.width());
        }
        // A name in characters two columns wide each fits too.
        let wide = pb::JobSummary { name: "森の光".repeat(20), ..Default::default() };
        for line in job_table(&[JobRow::of(wide, 0)]).lines() {
            assert!(line.width() <= COLUMNS, "{} columns: {line}", line.width());
        }
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines.len(), 5, "{t}");
        assert!(lines[1].contains("40/120 f7/24") && lines[1].contains("8.0s"), "{t}");
        assert!(lines[1].contains("12.5s") && lines[1].ends_with('…'), "{t}");
        assert!(lines[2].starts_with("  127.0.0.1:50151 preparing"), "{t}");
        assert!(lines[4].starts_with("  no worker could render strip 3"), "{t}");
        // --wide keeps every word.
        assert!(wide_job_table(&rows).contains(long));
    }

    #[test]
    fn a_running_jobs_times_count_to_now() {
        let s = pb::JobSummary {
            submitted_unix_ms: 1_000,
            started_unix_ms: 3_000,
            ..Default::default()
        };
        let r = JobRow::of(s, 10_000);
        assert_eq!((r.queued_s, r.running_s), (Some(2.0), Some(7.0)));
        let s = pb::JobSummary {
            submitted_unix_ms: 1_000,
            finished_unix_ms: 1_500,
            ..Default::default()
        };
        let r = JobRow::of(s, 10_000);
        assert_eq!((r.queued_s, r.running_s), (Some(0.5), None), "cancelled while queued");
    }
}
