//! The actor that owns the planner (MiniLM, the GGUF model, the HTTP
//! client). It runs on its own thread: model inference and blocking HTTP
//! calls never stall the async runtime, and requests are served in order.

use tokio::sync::oneshot;
use vlnav_runtime::actor::Mailbox;

use crate::plan::{Plan, Planned};
use crate::planner::{PlanError, Planner};

pub enum Msg {
    Plan {
        instruction: String,
        backend: String,
        reply: oneshot::Sender<Result<Planned, PlanError>>,
    },
    Replan {
        plan: Plan,
        failed_step: usize,
        failure: String,
        answer: String,
        backend: String,
        reply: oneshot::Sender<Result<Planned, PlanError>>,
    },
}

/// Mailbox depth: requests beyond it wait for space (backpressure).
pub const MAILBOX: usize = 64;

/// Starts the actor thread; it stops when every mailbox handle is dropped.
pub fn spawn(mut planner: Planner) -> Mailbox<Msg> {
    let (mailbox, mut rx) = Mailbox::channel("planner", MAILBOX);
    std::thread::Builder::new()
        .name("planner-actor".into())
        .spawn(move || {
            while let Some(msg) = rx.blocking_recv() {
                match msg {
                    Msg::Plan { instruction, backend, reply } => {
                        let _ = reply.send(planner.plan(&instruction, &backend));
                    }
                    Msg::Replan { plan, failed_step, failure, answer, backend, reply } => {
                        let _ = reply.send(planner.replan(&plan, failed_step, &failure, &answer, &backend));
                    }
                }
            }
        })
        .expect("spawning the planner actor thread");
    mailbox
}
