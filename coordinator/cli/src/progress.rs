//! Progress for long work: bars on a terminal, plain lines on stderr
//! elsewhere (a log file, CI), so a long render never runs silent.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar over the three channels of an LB solve.
pub fn lb_bar(label: &str, cap: usize) -> ProgressBar {
    let bar = ProgressBar::new(3 * cap as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:40}] {msg} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar
}

/// A callback that moves `bar` for `solve`'s `(channel, step, cap)`.
pub fn lb_callback(bar: &ProgressBar) -> impl Fn(usize, usize, usize) + '_ {
    move |channel, step, cap| {
        bar.set_position((channel * cap + step) as u64);
        bar.set_message(format!("{} step {step}/{cap}", ["red", "green", "blue"][channel]));
    }
}

/// Shows `m` as the stage `bar` is at: its message on a terminal, a line on
/// stderr where the bar is hidden.
pub fn stage(bar: &ProgressBar, m: &str) {
    if bar.is_hidden() {
        eprintln!("{m}");
    } else {
        bar.set_message(m.to_string());
    }
}
