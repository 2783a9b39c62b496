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

/// Buckets of the whole-run history per signal: a 2 h run at 8 kHz in 4096 columns.
const HISTORY_BUCKETS: usize = 4096;
/// Width of a history bucket at the start of a run, s (doubles as the run outgrows them).
const HISTORY_START_WIDTH_S: f64 = 0.01;

/// A min/max history of the whole run, per signal, in a bounded number of time buckets:
/// when the run outgrows them, neighbours merge and the width doubles, so memory stays
/// fixed however long the run (a 2 h warm-up shows its trend).
#[derive(Default)]
pub struct History {
    /// Width of one bucket, s.
    pub width_s: f64,
    /// Per signal, per bucket: (min, max); (∞, −∞) for a bucket without samples.
    lo: Vec<Vec<f64>>,
    hi: Vec<Vec<f64>>,
}

impl History {
    fn reset(&mut self, signals: usize) {
        self.width_s = HISTORY_START_WIDTH_S;
        self.lo = vec![Vec::new(); signals];
        self.hi = vec![Vec::new(); signals];
    }

    /// Adds one row (`t_s` and every signal's value).
    fn push(&mut self, t_s: f64, row: impl Iterator<Item = f64>) {
        if !t_s.is_finite() || t_s < 0.0 || self.width_s <= 0.0 {
            return;
        }
        let mut b = (t_s / self.width_s) as usize;
        while b >= HISTORY_BUCKETS {
            self.merge();
            b = (t_s / self.width_s) as usize;
        }
        for ((lo, hi), v) in self.lo.iter_mut().zip(self.hi.iter_mut()).zip(row) {
            while lo.len() <= b {
                lo.push(f64::INFINITY);
                hi.push(f64::NEG_INFINITY);
            }
            if v.is_finite() {
                lo[b] = lo[b].min(v);
                hi[b] = hi[b].max(v);
            }
        }
    }

    /// Merges neighbouring buckets: half as many, twice as wide.
    fn merge(&mut self) {
        for (lo, hi) in self.lo.iter_mut().zip(self.hi.iter_mut()) {
            *lo = lo
                .chunks(2)
                .map(|c| c.iter().copied().fold(f64::INFINITY, f64::min))
                .collect();
            *hi = hi
                .chunks(2)
                .map(|c| c.iter().copied().fold(f64::NEG_INFINITY, f64::max))
                .collect();
        }
        self.width_s *= 2.0;
    }

    /// Signal `i` as plot points, at most two per pixel column of `width_px`: each
    /// column's minimum then maximum, shown through `show`.
    pub fn points(&self, i: usize, width_px: usize, show: fn(f64) -> f64) -> Vec<[f64; 2]> {
        let (Some(lo), Some(hi)) = (self.lo.get(i), self.hi.get(i)) else {
            return vec![];
        };
        let group = lo.len().div_ceil(width_px.max(1)).max(1);
        let w = self.width_s * group as f64;
        lo.chunks(group)
            .zip(hi.chunks(group))
            .enumerate()
            .flat_map(|(k, (l, h))| {
                let mn = l.iter().copied().fold(f64::INFINITY, f64::min);
                let mx = h.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let t0 = k as f64 * w;
                (mn.is_finite() && mx.is_finite())
                    .then(|| [[t0 + 0.25 * w, show(mn)], [t0 + 0.75 * w, show(mx)]])
                    .into_iter()
                    .flatten()
            })
            .collect()
    }

    /// Signal `i` near `t_s`: the middle of its bucket's range (the history keeps no more).
    pub fn value_at(&self, i: usize, t_s: f64) -> Option<f64> {
        let b = (t_s / self.width_s).floor();
        if !b.is_finite() || b < 0.0 {
            return None;
        }
        let b = b as usize;
        let (l, h) = (*self.lo.get(i)?.get(b)?, *self.hi.get(i)?.get(b)?);
        (l.is_finite() && h.is_finite()).then_some(0.5 * (l + h))
    }
}

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

    /// Whether no sample has arrived since the last reset.
    pub fn is_empty(&self) -> bool {
        self.cols.first().is_none_or(VecDeque::is_empty)
    }

    /// The position of column `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Moves the machine's new trace rows into the ring and the whole-run history.
    fn take_from(&mut self, m: &mut Machine, hist: &mut History) {
        let same = self.names.len() == m.trace.signals.len()
            && self
                .names
                .iter()
                .zip(&m.trace.signals)
                .all(|(n, s)| *n == s.name);
        if !same {
            self.relayout(m);
            hist.reset(self.names.len());
        }
        let rows = m.trace.len();
        for r in 0..rows {
            if let Some(t) = m.trace.signals.first().map(|s| s.data[r]) {
                hist.push(t, m.trace.signals.iter().map(|s| s.data[r]));
            }
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
    /// The whole run, decimated.
    pub history: History,
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
        self.ring.take_from(&mut self.machine, &mut self.history);
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
        let mut history = History::default();
        history.reset(ring.names.len());
        Live {
            shared: Arc::new(Mutex::new(Shared {
                machine,
                running: false,
                speed: 1.0,
                ring,
                history,
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
        let n = s.ring.names.len();
        s.history.reset(n);
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
