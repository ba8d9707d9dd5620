//! Progress of a stage's work: one small interface the stage libraries report to, shown by
//! the binaries as an indicatif spinner or bar on stderr (hidden when stderr is not a terminal
//! or with `--quiet`), and silent in tests.

use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

/// What a stage reports while it works. Calls are cheap; call them from any thread.
pub trait Progress: Sync {
    /// A new phase begins ("links", "solve"); shown as the message, any bar is reset.
    fn phase(&self, name: &str);
    /// The current phase has `total` units of work: a bar from now on.
    fn total(&self, total: u64);
    /// `n` more units of the current phase are done.
    fn advance(&self, n: u64);
    /// A line worth keeping above the bar (a solver's iteration); only shown on a terminal.
    fn note(&self, line: &str);
}

/// Reports nowhere (tests, library callers).
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Progress for Silent {
    fn phase(&self, _: &str) {}
    fn total(&self, _: u64) {}
    fn advance(&self, _: u64) {}
    fn note(&self, _: &str) {}
}

/// An indicatif display named after the stage: a spinner with the phase, or a bar once the
/// phase's total is known.
pub struct Bar {
    bar: ProgressBar,
    name: &'static str,
}

impl Bar {
    /// A display for `name` ("pc-vmap"), hidden when `quiet`.
    pub fn new(name: &'static str, quiet: bool) -> Bar {
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            ProgressBar::new_spinner()
        };
        let b = Bar { bar, name };
        b.spinner();
        b.bar.enable_steady_tick(Duration::from_millis(100));
        b
    }

    fn spinner(&self) {
        let template = format!("{{spinner}} {} {{msg}} {{elapsed}}", self.name);
        if let Ok(style) = ProgressStyle::with_template(&template) {
            self.bar.set_style(style);
        }
    }

    /// Removes the display (before the summary line is printed).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Progress for Bar {
    fn phase(&self, name: &str) {
        self.spinner();
        self.bar.set_length(0);
        self.bar.set_position(0);
        self.bar.set_message(name.to_string());
    }

    fn total(&self, total: u64) {
        let template = format!(
            "{{spinner}} {} {{msg}} [{{bar:30}}] {{human_pos}}/{{human_len}} {{elapsed}}",
            self.name
        );
        if let Ok(style) = ProgressStyle::with_template(&template) {
            self.bar.set_style(style.progress_chars("=> "));
        }
        self.bar.set_length(total);
    }

    fn advance(&self, n: u64) {
        self.bar.inc(n);
    }

    fn note(&self, line: &str) {
        self.bar.println(line);
    }
}
