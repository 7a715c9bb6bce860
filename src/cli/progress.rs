//! A terminal progress bar fed by the pipeline's [`Progress`] callbacks.

use indicatif::{ProgressBar, ProgressStyle};
use meshsmooth_core::{Progress, Stage};
use std::sync::atomic::{AtomicU8, Ordering};

/// Steps of the bar per stage.
const STEPS: u64 = 1000;

/// One bar per run: the message names the stage, the bar shows the
/// fraction of that stage. Hidden when not shown on a terminal.
pub struct Bar {
    bar: ProgressBar,
    /// `Stage as u8 + 1` of the stage on display, 0 before the first.
    stage: AtomicU8,
}

impl Bar {
    /// A bar drawn on stderr when `show`, otherwise a hidden one.
    pub fn new(show: bool) -> Self {
        let bar = if show {
            ProgressBar::new(STEPS)
        } else {
            ProgressBar::hidden()
        };
        if let Ok(style) =
            ProgressStyle::with_template("{spinner} {elapsed:>4} {msg:>9} [{bar:40}] {percent:>3}%")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        Bar {
            bar,
            stage: AtomicU8::new(0),
        }
    }

    /// Removes the bar from the terminal.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Progress for Bar {
    fn update(&self, stage: Stage, fraction: f64) {
        let id = stage as u8 + 1;
        if self.stage.swap(id, Ordering::Relaxed) != id {
            self.bar.set_message(stage.name());
        }
        let fraction = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.bar.set_position((fraction * STEPS as f64) as u64);
    }
}
