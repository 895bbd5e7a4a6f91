//! A job as the coordinator takes it, from a frame's settings: what
//! `sylva render` (through its loopback farm), `sylva submit` and `bench
//! sequence` send.

use sylva_coordinator::schedule::ScheduleKind;
use sylva_coordinator::service::MAX_NAME;
use sylva_scene::frame::FrameSettings;
use sylva_scene::sequence::View;

/// A job for the coordinator: the frame (and a sequence's views), how to
/// cut it, its priority and label.
pub fn job_spec(
    frame: &FrameSettings,
    views: &[View],
    schedule: ScheduleKind,
    priority: i32,
    name: &str,
) -> sylva_proto::pb::JobSpec {
    use sylva_proto::pb;
    sylva_proto::pb::JobSpec {
        views: views.iter().map(pb::FrameView::from).collect(),
        frame: Some(pb::FrameSettings::from(frame)),
        schedule: sylva_proto::convert::schedule_to_wire(schedule).into(),
        priority,
        // The coordinator refuses names over MAX_NAME bytes: cut at a character.
        name: cut(name, MAX_NAME),
        submitter: cut(&submitter_name(), sylva_coordinator::service::MAX_SUBMITTER),
    }
}

/// `s` cut at a character so it holds at most `max` bytes, without the
/// characters the coordinator refuses (control and bidirectional formatting).
fn cut(s: &str, max: usize) -> String {
    s.chars()
        .filter(|&c| !sylva_coordinator::service::unprintable(c))
        .scan(0, |n, c| {
            (*n + c.len_utf8() <= max).then(|| {
                *n += c.len_utf8();
                c
            })
        })
        .collect()
}

/// Who submits, for listings: `$SYLVA_USER`, else the login name.
fn submitter_name() -> String {
    ["SYLVA_USER", "USER", "LOGNAME"]
        .iter()
        .find_map(|v| std::env::var(v).ok().filter(|u| !u.is_empty()))
        .unwrap_or_default()
}
