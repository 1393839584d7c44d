//! Mission records, their ordered event logs and live watchers. Every change
//! is persisted before it is broadcast; a watcher that falls behind re-reads
//! what it missed, so no event is ever lost to a slow client.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tokio::sync::broadcast;
use vlnav_proto::v1::{Finished, Mission, MissionEvent, MissionState, mission_event::Kind};

use crate::store::{Store, StoreError};

pub(crate) fn is_terminal(state: MissionState) -> bool {
    matches!(state, MissionState::Succeeded | MissionState::Failed | MissionState::Cancelled | MissionState::Planned)
}

struct Entry {
    mission: Mission,
    events: Vec<MissionEvent>,
    live: broadcast::Sender<MissionEvent>,
}

pub(crate) struct Hub {
    entries: Mutex<HashMap<String, Entry>>,
    store: Store,
}

/// What a new watcher gets: the log so far and the live feed after it.
pub(crate) struct Watch {
    pub(crate) backlog: Vec<MissionEvent>,
    pub(crate) live: broadcast::Receiver<MissionEvent>,
    pub(crate) finished: bool,
}

/// Why an unfinished mission found at start-up is not resumed.
pub(crate) const RESTART_REASON: &str = "the gateway restarted while this mission was unfinished; it is not resumed \
because the robot may have moved and its odometry anchor and target estimates are gone — submit it again";

impl Hub {
    /// Loads every stored mission. Unfinished ones are marked FAILED (see
    /// [`RESTART_REASON`]) with a `Finished` event, so watchers and lists agree.
    pub(crate) fn open(store: Store) -> Result<Arc<Self>, StoreError> {
        let mut entries = HashMap::new();
        for mut mission in store.missions()? {
            let mut events = store.events(&mission.mission_id)?;
            let state = MissionState::try_from(mission.state).unwrap_or(MissionState::Unspecified);
            if !is_terminal(state) {
                mission.state = MissionState::Failed as i32;
                mission.reason = RESTART_REASON.to_string();
                let event = MissionEvent {
                    mission_id: mission.mission_id.clone(),
                    seq: events.last().map_or(1, |e| e.seq + 1),
                    stamp: events.last().map_or(0.0, |e| e.stamp),
                    kind: Some(Kind::Finished(Finished {
                        state: MissionState::Failed as i32,
                        reason: RESTART_REASON.to_string(),
                        metrics: mission.metrics,
                    })),
                };
                store.save(&mission, Some(&event))?;
                events.push(event);
            }
            let (live, _) = broadcast::channel(256);
            entries.insert(mission.mission_id.clone(), Entry { mission, events, live });
        }
        Ok(Arc::new(Self { entries: Mutex::new(entries), store }))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Entry>> {
        // A panic elsewhere must not take every mission down with it.
        self.entries.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(crate) fn create(&self, mission: Mission) -> Result<(), StoreError> {
        self.store.save(&mission, None)?;
        let (live, _) = broadcast::channel(256);
        self.lock().insert(mission.mission_id.clone(), Entry { mission, events: Vec::new(), live });
        Ok(())
    }

    pub(crate) fn get(&self, id: &str) -> Option<Mission> {
        self.lock().get(id).map(|e| e.mission.clone())
    }

    /// Newest first, optionally for one robot.
    pub(crate) fn list(&self, robot_id: &str, limit: usize) -> Vec<Mission> {
        let mut out: Vec<Mission> = self
            .lock()
            .values()
            .filter(|e| robot_id.is_empty() || e.mission.robot_id == robot_id)
            .map(|e| e.mission.clone())
            .collect();
        out.sort_by(|a, b| b.created_unix.total_cmp(&a.created_unix).then_with(|| b.mission_id.cmp(&a.mission_id)));
        out.truncate(limit);
        out
    }

    /// Changes a mission and, optionally, appends an event — persisted
    /// together, then broadcast. A `Finished` event also sets the state.
    pub(crate) fn record(
        &self,
        id: &str,
        stamp: f64,
        kind: Option<Kind>,
        change: impl FnOnce(&mut Mission),
    ) -> Result<Mission, StoreError> {
        let mut entries = self.lock();
        let entry = entries.get_mut(id).ok_or_else(|| StoreError::Db(format!("no mission {id}")))?;
        let mut mission = entry.mission.clone();
        change(&mut mission);
        if let Some(Kind::Finished(f)) = &kind {
            mission.state = f.state;
            mission.reason = f.reason.clone();
            mission.metrics = f.metrics;
        }
        let event = kind.map(|kind| MissionEvent {
            mission_id: id.to_string(),
            seq: entry.events.last().map_or(1, |e| e.seq + 1),
            stamp,
            kind: Some(kind),
        });
        self.store.save(&mission, event.as_ref())?;
        entry.mission = mission.clone();
        if let Some(event) = event {
            entry.events.push(event.clone());
            let _ = entry.live.send(event);
        }
        Ok(mission)
    }

    pub(crate) fn watch(&self, id: &str) -> Option<Watch> {
        let entries = self.lock();
        let entry = entries.get(id)?;
        Some(Watch {
            backlog: entry.events.clone(),
            live: entry.live.subscribe(),
            finished: entry.events.iter().any(|e| matches!(e.kind, Some(Kind::Finished(_)))),
        })
    }

    /// Events after `seq`, for a watcher that lagged behind the live feed.
    pub(crate) fn events_after(&self, id: &str, seq: u64) -> Vec<MissionEvent> {
        self.lock().get(id).map(|e| e.events.iter().filter(|ev| ev.seq > seq).cloned().collect()).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlnav_proto::v1::{StepStarted, Transcribed};

    fn mission(id: &str, state: MissionState) -> Mission {
        Mission { mission_id: id.into(), robot_id: "husky-1".into(), state: state as i32, ..Default::default() }
    }

    #[test]
    fn events_persist_in_order_and_unfinished_missions_fail_cleanly_after_a_restart() {
        let dir = tempfile::tempdir().unwrap();
        {
            let hub = Hub::open(Store::open(dir.path()).unwrap()).unwrap();
            hub.create(mission("m-done", MissionState::Running)).unwrap();
            hub.create(mission("m-open", MissionState::Running)).unwrap();
            hub.record(
                "m-open",
                0.0,
                Some(Kind::Transcribed(Transcribed { transcript: "hi".into(), audio_seconds: 1.0 })),
                |_| {},
            )
            .unwrap();
            hub.record("m-open", 2.5, Some(Kind::StepStarted(StepStarted { index: 0, ..Default::default() })), |m| {
                m.current_step = 0
            })
            .unwrap();
            hub.record(
                "m-done",
                9.0,
                Some(Kind::Finished(Finished { state: MissionState::Succeeded as i32, ..Default::default() })),
                |_| {},
            )
            .unwrap();
        }
        let hub = Hub::open(Store::open(dir.path()).unwrap()).unwrap();
        assert_eq!(hub.get("m-done").unwrap().state, MissionState::Succeeded as i32);
        let open = hub.get("m-open").unwrap();
        assert_eq!(open.state, MissionState::Failed as i32);
        assert_eq!(open.reason, RESTART_REASON);
        let w = hub.watch("m-open").unwrap();
        let seqs: Vec<u64> = w.backlog.iter().map(|e| e.seq).collect();
        assert_eq!(seqs, vec![1, 2, 3]);
        assert!(w.finished);
        assert!(matches!(w.backlog[2].kind, Some(Kind::Finished(_))));
        assert_eq!(hub.list("", 10).len(), 2);
        assert_eq!(hub.list("other-robot", 10).len(), 0);
    }
}
