//! When a long-running Sylva process stops.

/// Resolves on Ctrl-C or SIGTERM.
pub async fn signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        if let Ok(mut s) = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        {
            s.recv().await;
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("shutting down");
}

/// One shutdown that several servers of a process wait for (the API and
/// the dashboard beside it): every [`Shutdown::wait`] resolves once the
/// trigger has.
#[derive(Clone, Debug)]
pub struct Shutdown(tokio::sync::watch::Receiver<bool>);

impl Shutdown {
    /// A shutdown that `trigger` (as [`signal`]) sets off; call within a
    /// Tokio runtime.
    pub fn new(trigger: impl Future<Output = ()> + Send + 'static) -> Self {
        let (tx, rx) = tokio::sync::watch::channel(false);
        tokio::spawn(async move {
            trigger.await;
            let _ = tx.send(true);
        });
        Self(rx)
    }

    /// Resolves once the shutdown is set off.
    pub fn wait(&self) -> impl Future<Output = ()> + Send + 'static {
        let mut rx = self.0.clone();
        async move {
            // An error: the trigger's task is gone with the runtime.
            let _ = rx.wait_for(|&down| down).await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn every_waiter_hears_one_shutdown() {
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let down = Shutdown::new(async move {
            let _ = rx.await;
        });
        let (a, b) = (tokio::spawn(down.wait()), tokio::spawn(down.clone().wait()));
        tokio::task::yield_now().await;
        assert!(!a.is_finished() && !b.is_finished());
        tx.send(()).unwrap();
        a.await.unwrap();
        b.await.unwrap();
        down.wait().await; // and one that comes late
    }
}
