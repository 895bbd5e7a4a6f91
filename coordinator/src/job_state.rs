//! A job's state and the transitions between them, in one place (as
//! Flamenco's task state machine): queued → running → done, failed or
//! cancelled, and queued → cancelled. Every change of a job's state goes
//! through [`JobState::to`], so a finished job never runs again and a
//! cancelled one is never marked done.

use sylva_proto::pb;

/// Where a job is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum JobState {
    /// Waiting for a running slot.
    Queued,
    /// Its strips are on the workers.
    Running,
    /// Its result is stored.
    Done,
    /// It ended with an error.
    Failed,
    /// A client cancelled it.
    Cancelled,
}

/// A change of state the machine does not allow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("a {from} job cannot become {to}")]
pub struct Transition {
    /// The state the job is in.
    pub from: JobState,
    /// The state asked for.
    pub to: JobState,
}

impl JobState {
    /// Every state, in the order of a job's life.
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Done,
        JobState::Failed,
        JobState::Cancelled,
    ];

    /// The state's name as the CLI, the dashboard and stats files spell it.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    /// Parses a state's name.
    pub fn from_name(name: &str) -> Option<JobState> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Whether the job has ended (done, failed or cancelled): final.
    pub fn ended(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed | JobState::Cancelled)
    }

    /// Whether a job that ended so may be run again as a new job
    /// (failed or cancelled; a done job has its result).
    pub fn requeueable(self) -> bool {
        matches!(self, JobState::Failed | JobState::Cancelled)
    }

    /// The state after a change to `to`, if the machine allows it.
    pub fn to(self, to: JobState) -> Result<JobState, Transition> {
        use JobState::*;
        match (self, to) {
            (Queued, Running | Cancelled | Failed) | (Running, Done | Failed | Cancelled) => Ok(to),
            _ => Err(Transition { from: self, to }),
        }
    }

    /// The state's wire value.
    pub fn to_wire(self) -> i32 {
        let w = match self {
            JobState::Queued => pb::JobState::Queued,
            JobState::Running => pb::JobState::Running,
            JobState::Done => pb::JobState::Done,
            JobState::Failed => pb::JobState::Failed,
            JobState::Cancelled => pb::JobState::Cancelled,
        };
        w as i32
    }

    /// The state a wire value names; `None` for unspecified or unknown
    /// values (a newer server's).
    pub fn from_wire(v: i32) -> Option<JobState> {
        match pb::JobState::try_from(v).ok()? {
            pb::JobState::Unspecified => None,
            pb::JobState::Queued => Some(JobState::Queued),
            pb::JobState::Running => Some(JobState::Running),
            pb::JobState::Done => Some(JobState::Done),
            pb::JobState::Failed => Some(JobState::Failed),
            pb::JobState::Cancelled => Some(JobState::Cancelled),
        }
    }
}

impl std::fmt::Display for JobState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The name of a job state as it came over the wire ("unknown" for a value
/// this client does not know).
pub fn wire_name(v: i32) -> &'static str {
    JobState::from_wire(v).map_or("unknown", JobState::name)
}

/// Whether a job state from the wire is final; an unknown one is not.
pub fn wire_ended(v: i32) -> bool {
    JobState::from_wire(v).is_some_and(JobState::ended)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_moves_only_forward_and_ends_for_good() {
        use JobState::*;
        for s in JobState::ALL {
            assert_eq!(JobState::from_name(s.name()), Some(s));
            assert_eq!(JobState::from_wire(s.to_wire()), Some(s));
            if s.ended() {
                for t in JobState::ALL {
                    assert!(s.to(t).is_err(), "{s} → {t}");
                }
            }
        }
        assert_eq!(Queued.to(Running), Ok(Running));
        assert_eq!(Running.to(Done), Ok(Done));
        assert_eq!(Queued.to(Cancelled), Ok(Cancelled));
        assert!(Queued.to(Done).is_err(), "a job is done only after it ran");
        assert!(Running.to(Queued).is_err());
        assert_eq!(
            Cancelled.to(Done).unwrap_err().to_string(),
            "a cancelled job cannot become done"
        );
        assert_eq!(JobState::from_wire(0), None);
        assert_eq!(wire_name(99), "unknown");
        assert!(!wire_ended(0));
    }
}
