//! A minimal actor pattern: a task owns its state and drains a bounded
//! mailbox; callers send a message carrying a oneshot reply channel.
//! Backpressure comes from the mailbox bound, never from dropping messages.

use tokio::sync::{mpsc, oneshot};

/// The actor task is gone (it panicked or was shut down).
#[derive(Debug, thiserror::Error)]
#[error("the {0} actor is not running")]
pub struct ActorGone(pub &'static str);

impl From<ActorGone> for tonic::Status {
    fn from(e: ActorGone) -> Self {
        tonic::Status::unavailable(e.to_string())
    }
}

/// The sending side of an actor's mailbox.
#[derive(Debug)]
pub struct Mailbox<M> {
    name: &'static str,
    tx: mpsc::Sender<M>,
}

impl<M> Clone for Mailbox<M> {
    fn clone(&self) -> Self {
        Self { name: self.name, tx: self.tx.clone() }
    }
}

impl<M: Send + 'static> Mailbox<M> {
    /// A mailbox of `capacity` messages and its receiving end, for the actor task.
    pub fn channel(name: &'static str, capacity: usize) -> (Self, mpsc::Receiver<M>) {
        let (tx, rx) = mpsc::channel(capacity);
        (Self { name, tx }, rx)
    }

    /// Sends a message and waits for the actor's reply.
    pub async fn call<R>(&self, make: impl FnOnce(oneshot::Sender<R>) -> M) -> Result<R, ActorGone> {
        let (reply, rx) = oneshot::channel();
        self.tx.send(make(reply)).await.map_err(|_| ActorGone(self.name))?;
        rx.await.map_err(|_| ActorGone(self.name))
    }

    /// Sends a message without waiting for a reply (waits for mailbox space).
    pub async fn tell(&self, msg: M) -> Result<(), ActorGone> {
        self.tx.send(msg).await.map_err(|_| ActorGone(self.name))
    }

    pub fn is_closed(&self) -> bool {
        self.tx.is_closed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    enum Msg {
        Add(u32, oneshot::Sender<u32>),
    }

    #[tokio::test]
    async fn call_round_trips_and_reports_a_gone_actor() {
        let (mb, mut rx) = Mailbox::channel("adder", 4);
        let task = tokio::spawn(async move {
            let mut total = 0;
            while let Some(Msg::Add(n, reply)) = rx.recv().await {
                total += n;
                let _ = reply.send(total);
            }
        });
        assert_eq!(mb.call(|r| Msg::Add(2, r)).await.unwrap(), 2);
        assert_eq!(mb.call(|r| Msg::Add(3, r)).await.unwrap(), 5);
        task.abort();
        let _ = task.await;
        let err = mb.call(|r| Msg::Add(1, r)).await.unwrap_err();
        assert_eq!(err.to_string(), "the adder actor is not running");
    }
}
