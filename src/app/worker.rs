//! A computation on its own thread whose result belongs to the preset it started on: the
//! diagnosis and the tune. Progress, Cancel, the result, its [`Basis`] and whether it was
//! applied live here once, for both.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use super::Workbench;
use super::diagnose::Basis;

/// The running job: what the worker thread shares with the window.
pub struct Worker<P, R> {
    /// The job's own progress report, written by the thread, read by the window.
    pub progress: Arc<Mutex<P>>,
    /// Set by Cancel; the job returns an error when it sees it.
    pub cancel: Arc<AtomicBool>,
    result: Arc<Mutex<Option<Result<R, String>>>>,
    basis: Basis,
}

/// A job's state in the window: running, its last result and what that was computed on.
pub struct Computed<P, R> {
    pub job: Option<Worker<P, R>>,
    pub result: Option<R>,
    /// What `result` was computed on.
    pub basis: Option<Basis>,
    /// Whether `result` was applied to the preset.
    pub applied: bool,
    pub error: Option<String>,
}

impl<P, R> Default for Computed<P, R> {
    fn default() -> Self {
        Computed {
            job: None,
            result: None,
            basis: None,
            applied: false,
            error: None,
        }
    }
}

impl<P: Send + 'static, R: Send + 'static> Computed<P, R> {
    /// Runs `run` on its own thread, with the progress slot (starting at `progress`) and
    /// the cancel flag; the result will belong to `basis`.
    pub fn start(
        &mut self,
        basis: Basis,
        progress: P,
        run: impl FnOnce(&Mutex<P>, &AtomicBool) -> Result<R, String> + Send + 'static,
    ) {
        let job = Worker {
            progress: Arc::new(Mutex::new(progress)),
            cancel: Arc::new(AtomicBool::new(false)),
            result: Arc::new(Mutex::new(None)),
            basis,
        };
        let (progress, cancel, result) =
            (job.progress.clone(), job.cancel.clone(), job.result.clone());
        self.error = None;
        std::thread::spawn(move || {
            let r = run(&progress, &cancel);
            if let Ok(mut slot) = result.lock() {
                *slot = Some(r);
            }
        });
        self.job = Some(job);
    }

    /// Takes a finished job's result; returns it when one arrived now.
    pub fn poll(&mut self) -> Option<&R> {
        let done = self
            .job
            .as_ref()
            .and_then(|j| j.result.lock().ok().and_then(|mut r| r.take()))?;
        let job = self.job.take()?;
        match done {
            Ok(r) => {
                self.result = Some(r);
                self.basis = Some(job.basis);
                self.applied = false;
                self.result.as_ref()
            }
            Err(e) => {
                self.error = Some(e);
                None
            }
        }
    }

    /// Asks the running job to stop.
    pub fn cancel(&self) {
        if let Some(j) = &self.job {
            j.cancel.store(true, Ordering::Relaxed);
        }
    }

    /// Why the result cannot be applied to `wb` now: applied already, computed on an unknown
    /// preset, or on another one (see [`Basis::stale`]); None when it may.
    pub fn why_not(&self, wb: &Workbench) -> Option<String> {
        if self.applied {
            return Some("applied already (Undo restores the values before it)".into());
        }
        match &self.basis {
            Some(b) => b.stale(wb),
            None => Some("the result's preset is unknown: run it again to apply".into()),
        }
    }

    /// Waits until the running job has its result; the next frame takes it (tests).
    #[cfg(test)]
    pub fn wait(&self) {
        let finished = |j: &Worker<P, R>| j.result.lock().map(|r| r.is_some()).unwrap_or(true);
        while self.job.as_ref().is_some_and(|j| !finished(j)) {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    }
}
