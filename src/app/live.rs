//! The live model: a worker thread advances the machine at the chosen speed and keeps the
//! last minute of samples in a rolling buffer the plots read from. The UI and the worker
//! share one lock; the worker holds it for at most a couple of milliseconds at a time so
//! the UI keeps its frame rate. Tests drive the same code synchronously with `advance`.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use axisbench::Machine;

/// Samples kept per signal: a 60 s window at 8 kHz (about 100 MB for 25 signals).
const RING_CAP: usize = 480_000;
/// Longest the rolling window can be, s.
pub const MAX_WINDOW_S: f64 = 60.0;

/// The last samples of every trace signal, oldest first.
#[derive(Default)]
pub struct Ring {
    pub names: Vec<String>,
    pub units: Vec<String>,
    pub cols: Vec<VecDeque<f64>>,
    keep_every: usize,
    counter: usize,
}

impl Ring {
    fn relayout(&mut self, m: &Machine) {
        self.names = m.trace.signals.iter().map(|s| s.name.clone()).collect();
        self.units = m.trace.signals.iter().map(|s| s.unit.clone()).collect();
        self.cols = vec![VecDeque::new(); self.names.len()];
        let row_dt = m.t3_s * m.preset.scenario.trace_every.max(1) as f64;
        self.keep_every = ((MAX_WINDOW_S / row_dt) / RING_CAP as f64).ceil().max(1.0) as usize;
        self.counter = 0;
    }

    /// Moves the machine's new trace rows into the ring.
    fn take_from(&mut self, m: &mut Machine) {
        let same = self.names.len() == m.trace.signals.len()
            && self
                .names
                .iter()
                .zip(&m.trace.signals)
                .all(|(n, s)| *n == s.name);
        if !same {
            self.relayout(m);
        }
        let rows = m.trace.len();
        for r in 0..rows {
            self.counter += 1;
            if self.counter < self.keep_every {
                continue;
            }
            self.counter = 0;
            for (col, s) in self.cols.iter_mut().zip(&m.trace.signals) {
                if col.len() >= RING_CAP {
                    col.pop_front();
                }
                col.push_back(s.data[r]);
            }
        }
        m.trace.clear();
    }

    pub fn col(&self, name: &str) -> Option<&VecDeque<f64>> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| &self.cols[i])
    }

    pub fn unit(&self, name: &str) -> &str {
        self.names
            .iter()
            .position(|n| n == name)
            .map_or("", |i| self.units[i].as_str())
    }

    pub fn t_last(&self) -> f64 {
        self.cols
            .first()
            .and_then(|c| c.back().copied())
            .unwrap_or(0.0)
    }

    /// The ring as a trace (for "record to CSV").
    pub fn to_trace(&self) -> axisbench::Trace {
        let mut tr = axisbench::Trace::new();
        tr.meta
            .push(("source".into(), "simulated (axisbench workbench)".into()));
        if let Some(t) = self.cols.first() {
            tr.signals[0].data = t.iter().copied().collect();
        }
        for ((n, u), c) in self.names.iter().zip(&self.units).zip(&self.cols).skip(1) {
            let i = tr.add_signal(n, u);
            tr.signals[i].data = c.iter().copied().collect();
        }
        tr
    }
}

/// Everything the worker and the UI share.
pub struct Shared {
    pub machine: Machine,
    pub running: bool,
    /// Machine time per wall time.
    pub speed: f64,
    pub ring: Ring,
    /// Steps still to run while paused (the Step button).
    pub steps_pending: u64,
    /// Fractional steps carried between worker rounds.
    carry: f64,
    /// Why the model stopped by itself (it diverged, or its trace filled up); cleared by a
    /// reset.
    pub fault: Option<String>,
}

impl Shared {
    /// Runs up to `n` T3 steps (stopping at the program end) and collects their samples.
    /// A model that leaves every physical range stops here with its reason, so the plots
    /// never fill with non-finite numbers.
    pub fn step_n(&mut self, n: u64) {
        if self.fault.is_some() {
            self.running = false;
            return;
        }
        for _ in 0..n {
            if self.machine.done() {
                self.running = false;
                break;
            }
            self.machine.step();
        }
        if let Err(e) = self.machine.health() {
            self.running = false;
            self.fault = Some(e.to_string());
            return;
        }
        self.ring.take_from(&mut self.machine);
    }
}

pub struct Live {
    shared: Arc<Mutex<Shared>>,
    worker: Option<(JoinHandle<()>, Arc<AtomicBool>)>,
}

impl Live {
    pub fn new(machine: Machine) -> Live {
        let mut ring = Ring::default();
        ring.relayout(&machine);
        Live {
            shared: Arc::new(Mutex::new(Shared {
                machine,
                running: false,
                speed: 1.0,
                ring,
                steps_pending: 0,
                carry: 0.0,
                fault: None,
            })),
            worker: None,
        }
    }

    /// Locks the shared state. A worker that panicked leaves the data as it was; the UI
    /// keeps going with it rather than losing the user's session.
    pub fn lock(&self) -> MutexGuard<'_, Shared> {
        match self.shared.lock() {
            Ok(g) => g,
            Err(poisoned) => poisoned.into_inner(),
        }
    }

    /// Replaces the machine (reset, new preset or program) and clears the plots.
    pub fn replace(&self, machine: Machine) {
        let mut s = self.lock();
        s.ring.relayout(&machine);
        s.machine = machine;
        s.carry = 0.0;
        s.steps_pending = 0;
        s.fault = None;
    }

    /// Synchronous stepping (tests, the Step button when no worker runs).
    pub fn advance(&self, steps: u64) {
        self.lock().step_n(steps);
    }

    /// Starts the background worker; `repaint` is called when new samples arrive.
    pub fn spawn(&mut self, repaint: impl Fn() + Send + 'static) {
        if self.worker.is_some() {
            return;
        }
        let stop = Arc::new(AtomicBool::new(false));
        let shared = Arc::clone(&self.shared);
        let stop2 = Arc::clone(&stop);
        let handle = std::thread::spawn(move || worker(shared, stop2, repaint));
        self.worker = Some((handle, stop));
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        if let Some((h, stop)) = self.worker.take() {
            stop.store(true, Ordering::Relaxed);
            let _ = h.join();
        }
    }
}

fn worker(shared: Arc<Mutex<Shared>>, stop: Arc<AtomicBool>, repaint: impl Fn()) {
    let mut last = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        // A stall (debugger, suspended laptop) must not turn into a burst of catch-up work.
        let wall = (now - last).as_secs_f64().min(0.1);
        last = now;
        let mut work = false;
        {
            let mut s = match shared.lock() {
                Ok(g) => g,
                Err(p) => p.into_inner(),
            };
            let t3 = s.machine.t3_s;
            if s.running {
                s.carry += s.speed * wall / t3;
                let want = s.carry.floor();
                s.carry -= want;
                // Bounded work per round; what does not fit is dropped, so a speed the
                // machine cannot reach runs as fast as it can instead of piling up.
                let n = (want as u64).min(40_000);
                if n > 0 {
                    s.step_n(n);
                    work = true;
                }
                if s.carry > 1e5 {
                    s.carry = 0.0;
                }
            } else if s.steps_pending > 0 {
                let n = s.steps_pending.min(40_000);
                s.steps_pending -= n;
                s.step_n(n);
                work = true;
            }
        }
        if work {
            repaint();
        }
        std::thread::sleep(Duration::from_millis(if work { 1 } else { 5 }));
    }
}
