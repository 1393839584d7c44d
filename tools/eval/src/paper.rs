//! The paper's published figures (docs/design.md §6), for the side-by-side tables.

/// One row of the paper's Table V (50 trials per environment).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableVRow {
    pub environment: &'static str,
    pub success_pct: f64,
    pub soft_collision_pct: f64,
    pub hard_collision_pct: f64,
    pub path_m: f64,
    pub drift_m: f64,
    pub drift_std_m: f64,
    /// Simulation (true) or the real Husky (false).
    pub simulated: bool,
}

pub const TABLE_V: [TableVRow; 7] = [
    TableVRow {
        environment: "Indoor",
        success_pct: 100.0,
        soft_collision_pct: 10.0,
        hard_collision_pct: 0.0,
        path_m: 12.4,
        drift_m: 0.03,
        drift_std_m: 0.01,
        simulated: true,
    },
    TableVRow {
        environment: "Garage",
        success_pct: 100.0,
        soft_collision_pct: 8.5,
        hard_collision_pct: 0.0,
        path_m: 20.8,
        drift_m: 0.05,
        drift_std_m: 0.03,
        simulated: true,
    },
    TableVRow {
        environment: "Campus",
        success_pct: 98.0,
        soft_collision_pct: 10.0,
        hard_collision_pct: 0.0,
        path_m: 30.5,
        drift_m: 0.05,
        drift_std_m: 0.02,
        simulated: true,
    },
    TableVRow {
        environment: "Forest",
        success_pct: 95.0,
        soft_collision_pct: 15.2,
        hard_collision_pct: 0.3,
        path_m: 15.5,
        drift_m: 0.08,
        drift_std_m: 0.01,
        simulated: true,
    },
    TableVRow {
        environment: "Tunnel",
        success_pct: 98.0,
        soft_collision_pct: 14.0,
        hard_collision_pct: 0.0,
        path_m: 25.2,
        drift_m: 0.05,
        drift_std_m: 0.02,
        simulated: true,
    },
    TableVRow {
        environment: "Indoor Lab",
        success_pct: 95.0,
        soft_collision_pct: 15.0,
        hard_collision_pct: 0.5,
        path_m: 12.4,
        drift_m: 0.10,
        drift_std_m: 0.02,
        simulated: false,
    },
    TableVRow {
        environment: "Outdoor Area",
        success_pct: 98.0,
        soft_collision_pct: 5.6,
        hard_collision_pct: 0.0,
        path_m: 124.6,
        drift_m: 0.05,
        drift_std_m: 0.01,
        simulated: false,
    },
];

/// One row of the paper's Table IV: success % per navigation modality.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableIvRow {
    pub scenario: &'static str,
    pub constraint: &'static str,
    pub geometric_pct: f64,
    pub visual_pct: f64,
    pub hybrid_pct: f64,
}

pub const TABLE_IV: [TableIvRow; 5] = [
    TableIvRow {
        scenario: "Featureless Corridor",
        constraint: "No visual landmarks",
        geometric_pct: 92.0,
        visual_pct: 15.0,
        hybrid_pct: 95.0,
    },
    TableIvRow {
        scenario: "Symmetric Room",
        constraint: "Geometric ambiguity",
        geometric_pct: 40.0,
        visual_pct: 94.0,
        hybrid_pct: 96.0,
    },
    TableIvRow {
        scenario: "Occluded Target",
        constraint: "Target not visible",
        geometric_pct: 85.0,
        visual_pct: 30.0,
        hybrid_pct: 91.0,
    },
    TableIvRow {
        scenario: "Precise Positioning",
        constraint: "Exact stopping required",
        geometric_pct: 96.0,
        visual_pct: 65.0,
        hybrid_pct: 98.0,
    },
    TableIvRow {
        scenario: "Complex Mission",
        constraint: "Sequential task execution",
        geometric_pct: 10.0,
        visual_pct: 25.0,
        hybrid_pct: 88.0,
    },
];

/// The Table V row named `environment` (exact name as printed in the paper).
pub fn table_v(environment: &str) -> Option<&'static TableVRow> {
    TABLE_V.iter().find(|r| r.environment == environment)
}

/// The Table IV row named `scenario`.
pub fn table_iv(scenario: &str) -> Option<&'static TableIvRow> {
    TABLE_IV.iter().find(|r| r.scenario == scenario)
}

impl TableIvRow {
    pub fn success_pct(&self, mode: crate::metrics::Mode) -> f64 {
        match mode {
            crate::metrics::Mode::Geometric => self.geometric_pct,
            crate::metrics::Mode::Visual => self.visual_pct,
            crate::metrics::Mode::Hybrid => self.hybrid_pct,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_found_by_their_printed_names() {
        assert_eq!(table_v("Forest").unwrap().hard_collision_pct, 0.3);
        assert_eq!(table_v("Indoor Lab").unwrap().path_m, 12.4);
        assert!(table_v("Moon").is_none());
        let corridor = table_iv("Featureless Corridor").unwrap();
        assert_eq!(corridor.success_pct(crate::metrics::Mode::Visual), 15.0);
        assert_eq!(table_iv("Complex Mission").unwrap().hybrid_pct, 88.0);
    }
}
