//! The embedded mission store (redb): mission records and their event logs,
//! encoded as their `vlnav.v1` protobuf messages. One write transaction per
//! change, so a crash never leaves a record without the event that caused it.

use std::path::Path;

use prost::Message;
use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use vlnav_proto::v1::{Mission, MissionEvent};

const MISSIONS: TableDefinition<&str, &[u8]> = TableDefinition::new("missions");
const EVENTS: TableDefinition<(&str, u64), &[u8]> = TableDefinition::new("events");

#[derive(Debug, thiserror::Error)]
pub(crate) enum StoreError {
    #[error("mission store: {0}")]
    Db(String),
    #[error("mission store holds an undecodable record for {0}: {1}")]
    Corrupt(String, prost::DecodeError),
}

macro_rules! db_err {
    ($($t:ty),*) => {$(impl From<$t> for StoreError { fn from(e: $t) -> Self { StoreError::Db(e.to_string()) } })*};
}
db_err!(redb::DatabaseError, redb::TransactionError, redb::TableError, redb::StorageError, redb::CommitError);

pub(crate) struct Store {
    db: Database,
}

impl Store {
    /// Opens (or creates) `dir/missions.redb`.
    pub(crate) fn open(dir: &Path) -> Result<Self, StoreError> {
        std::fs::create_dir_all(dir).map_err(|e| StoreError::Db(format!("cannot create {}: {e}", dir.display())))?;
        let db = Database::create(dir.join("missions.redb"))?;
        let tx = db.begin_write()?;
        tx.open_table(MISSIONS)?;
        tx.open_table(EVENTS)?;
        tx.commit()?;
        Ok(Self { db })
    }

    /// Writes the mission record and, if given, one event, atomically.
    pub(crate) fn save(&self, mission: &Mission, event: Option<&MissionEvent>) -> Result<(), StoreError> {
        let tx = self.db.begin_write()?;
        {
            let mut missions = tx.open_table(MISSIONS)?;
            missions.insert(mission.mission_id.as_str(), mission.encode_to_vec().as_slice())?;
            if let Some(e) = event {
                let mut events = tx.open_table(EVENTS)?;
                events.insert((e.mission_id.as_str(), e.seq), e.encode_to_vec().as_slice())?;
            }
        }
        tx.commit()?;
        Ok(())
    }

    pub(crate) fn missions(&self) -> Result<Vec<Mission>, StoreError> {
        let tx = self.db.begin_read()?;
        let table = tx.open_table(MISSIONS)?;
        let mut out = Vec::new();
        for row in table.iter()? {
            let (k, v) = row?;
            out.push(Mission::decode(v.value()).map_err(|e| StoreError::Corrupt(k.value().to_string(), e))?);
        }
        Ok(out)
    }

    pub(crate) fn events(&self, mission_id: &str) -> Result<Vec<MissionEvent>, StoreError> {
        let tx = self.db.begin_read()?;
        let table = tx.open_table(EVENTS)?;
        let mut out = Vec::new();
        for row in table.range((mission_id, 0)..=(mission_id, u64::MAX))? {
            let (_, v) = row?;
            out.push(MissionEvent::decode(v.value()).map_err(|e| StoreError::Corrupt(mission_id.to_string(), e))?);
        }
        Ok(out)
    }
}
