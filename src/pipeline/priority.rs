//! Scheduling priority of the stage threads in a replay.
//!
//! A replay's speed is the track stage's: it alone waits on itself (the labels of one
//! frame place the detector's windows for the next), and its detection runs on every
//! core (the two cameras side by side, [`crate::track::StereoTracker`]). The other
//! stages only have to keep pace. With every thread at the same priority they took the
//! cores from the detection while it ran and left one idle while the track stage
//! labeled alone, or while one camera's detection finished before the other's: 14 % of
//! two cores idle over a 480-frame cluttered replay (`perf sched`). Run behind it, they
//! fill those gaps instead (2.6 % idle, the replay 16 % faster on the same take).
//!
//! In a replay the source therefore reads ahead ten nice levels below the track stage,
//! and the stages after it run at the lowest priority (nice 19): they still get every
//! core the track stage does not use, and when they fall behind, the bounded channels
//! stop the track stage until they catch up, so none of them can starve. A live take
//! keeps every thread at the process's priority: its source must not miss a camera
//! frame, and its pace is the cameras'.

use super::frame::Stage;

/// Nice levels a replay's stage thread runs below the process's: none for the track
/// stage, [`SOURCE_NICE_STEP`] for the source, [`BEHIND_NICE_STEP`] for the stages after
/// the track stage.
pub(super) fn replay_nice_step(stage: Stage) -> i32 {
    match stage {
        Stage::Track => 0,
        Stage::Source => SOURCE_NICE_STEP,
        Stage::Stabilize | Stage::Solve | Stage::Enhance | Stage::Rig | Stage::Sinks => {
            BEHIND_NICE_STEP
        }
    }
}

/// How far the replay source runs below the track stage. Ten levels (a tenth of the
/// weight of a thread at the track stage's level): at nineteen the source fell behind
/// and the track stage waited for frames (106-111 frames/s against 111-113 on the
/// cluttered take above, with a 4-frame read-ahead).
pub(super) const SOURCE_NICE_STEP: i32 = 10;

/// How far the stages after the track stage run below it: to the lowest level.
pub(super) const BEHIND_NICE_STEP: i32 = 19;

/// Lowers the calling thread's priority by `step` nice levels (up to the lowest, 19).
/// Lowering needs no privilege. Only Linux has per-thread nice levels; elsewhere the
/// thread keeps its priority.
///
/// # Errors
/// The system's message when the priority could not be read or set.
pub(super) fn lower_this_thread(step: i32) -> Result<(), String> {
    if step <= 0 {
        return Ok(());
    }
    lower(step)
}

#[cfg(target_os = "linux")]
fn lower(step: i32) -> Result<(), String> {
    use rustix::process::{getpriority_process, setpriority_process};
    // On Linux the nice level is a thread's own: the thread's id names it alone.
    let me = Some(rustix::thread::gettid());
    let now = getpriority_process(me).map_err(|e| e.to_string())?;
    setpriority_process(me, now.saturating_add(step).min(19)).map_err(|e| e.to_string())
}

#[cfg(not(target_os = "linux"))]
fn lower(_step: i32) -> Result<(), String> {
    Ok(())
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn a_lowered_thread_runs_that_many_levels_below_its_parent_and_no_further_than_19() {
        let nice = || rustix::process::getpriority_process(Some(rustix::thread::gettid()));
        let parent = nice().unwrap();
        let (lowered, floor) = std::thread::spawn(move || {
            lower_this_thread(SOURCE_NICE_STEP).unwrap();
            let lowered = nice().unwrap();
            lower_this_thread(BEHIND_NICE_STEP).unwrap();
            (lowered, nice().unwrap())
        })
        .join()
        .unwrap();
        assert_eq!(lowered, (parent + SOURCE_NICE_STEP).min(19));
        assert_eq!(floor, 19);
        // The calling thread's own level is untouched.
        assert_eq!(nice().unwrap(), parent);
    }
}
