//! A simulated Husky driven by the real edge agent inside the test process,
//! in real time, with every frame's [`StepRecord`] kept for the assertions.

use std::sync::{Arc, Mutex};

use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use vlnav_edge_agent::{EdgeOptions, Hooks, StepRecord};
use vlnav_runtime::CancellationToken;

/// The edge agent of one simulated robot and what it did at each frame.
pub struct SimRobot {
    pub opts: EdgeOptions,
    records: Arc<Mutex<Vec<StepRecord>>>,
    token: CancellationToken,
    agent: Option<JoinHandle<anyhow::Result<()>>>,
}

impl SimRobot {
    /// Starts the agent (`opts.lockstep` should be false: real time).
    pub fn start(opts: EdgeOptions) -> SimRobot {
        let (tx, mut rx) = mpsc::unbounded_channel();
        let records = Arc::new(Mutex::new(Vec::new()));
        let keep = records.clone();
        tokio::spawn(async move {
            while let Some(r) = rx.recv().await {
                keep.lock().unwrap_or_else(|p| p.into_inner()).push(r);
            }
        });
        let token = CancellationToken::new();
        let hooks = Hooks { observer: Some(tx), ..Hooks::default() };
        let agent = tokio::spawn(vlnav_edge_agent::run_with(opts.clone(), token.clone(), hooks));
        SimRobot { opts, records, token, agent: Some(agent) }
    }

    pub fn robot_id(&self) -> &str {
        &self.opts.robot_id
    }

    /// The frame period, sensor seconds.
    pub fn period(&self) -> f64 {
        1.0 / self.opts.frame_rate
    }

    /// Every record so far.
    pub fn records(&self) -> Vec<StepRecord> {
        self.records.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// The newest record.
    pub fn latest(&self) -> Option<StepRecord> {
        self.records.lock().unwrap_or_else(|p| p.into_inner()).last().cloned()
    }

    /// Sensor time of the newest record (0 before the first).
    pub fn now(&self) -> f64 {
        self.latest().map_or(0.0, |r| r.stamp)
    }

    /// Stops the agent and returns how its run ended.
    pub async fn stop(mut self) -> anyhow::Result<()> {
        self.token.cancel();
        match self.agent.take() {
            Some(agent) => agent.await?,
            None => Ok(()),
        }
    }
}

impl Drop for SimRobot {
    fn drop(&mut self) {
        self.token.cancel();
    }
}
