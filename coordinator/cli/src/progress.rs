//! Progress bars for long solves (hidden when stderr is not a terminal).

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
