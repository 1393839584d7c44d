//! Local safety, independent of the network: a deadman measured in sensor
//! time, velocity and acceleration clamping, an explicit e-stop, and the
//! reconnect backoff. Pure logic, no I/O, no wall clock.

use std::time::Duration;

use vlnav_sim::Twist;

/// The robot's limits the governor enforces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub max_linear: f64,
    pub max_angular: f64,
    pub max_linear_accel: f64,
    pub max_angular_accel: f64,
}

/// Why the output is what it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// A fresh command (ramped by the acceleration limits); `clamped` when it
    /// exceeded the velocity limits.
    Commanded { clamped: bool },
    /// No command received yet.
    NoCommand,
    /// The newest command is older than the deadman timeout.
    DeadmanTripped,
    /// The e-stop is engaged.
    EStop,
}

impl Verdict {
    pub fn deadman_tripped(&self) -> bool {
        matches!(self, Verdict::DeadmanTripped | Verdict::NoCommand)
    }
}

/// Why the edge agent dropped a velocity command (docs/security.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dropped {
    /// The same sequence number as one already taken: a replay.
    Duplicate,
    /// A lower sequence number than one already taken: reordered or replayed.
    OutOfOrder,
    /// Its stamp is further behind the newest frame sent than the deadman window.
    Stale,
    /// Its stamp is newer than any frame this agent has sent: it answers
    /// nothing this robot saw.
    Unanswerable,
    /// It names a mission other than the one the gateway announced, or it
    /// would move the robot while no mission is announced.
    UnknownMission,
}

/// How many commands were dropped, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DroppedCounts {
    pub duplicate: u64,
    pub out_of_order: u64,
    pub stale: u64,
    pub unanswerable: u64,
    pub unknown_mission: u64,
}

impl DroppedCounts {
    pub fn total(&self) -> u64 {
        self.duplicate + self.out_of_order + self.stale + self.unanswerable + self.unknown_mission
    }
}

/// Admits a velocity command only if its sequence number is above every one
/// admitted on this link, it answers a frame this agent has sent, it is
/// within the deadman window of the newest frame (sensor time), and it
/// belongs to the mission the gateway announced (a command that moves the
/// robot needs one). Pure logic; one per link (a new link's gateway numbers
/// and announces afresh).
#[derive(Clone, Debug)]
pub struct CommandGate {
    deadman_timeout: f64,
    last_seq: Option<u64>,
    newest_frame: Option<f64>,
    /// The announced mission; empty when none is.
    announced: String,
    dropped: DroppedCounts,
}

impl CommandGate {
    pub fn new(deadman_timeout_s: f64) -> Self {
        Self {
            deadman_timeout: deadman_timeout_s.max(0.0),
            last_seq: None,
            newest_frame: None,
            announced: String::new(),
            dropped: Default::default(),
        }
    }

    /// The gateway announced that `mission_id` (empty: none) drives from now on.
    pub fn announce(&mut self, mission_id: &str) {
        self.announced.clear();
        self.announced.push_str(mission_id);
    }

    /// The announced mission; empty when none is.
    pub fn announced(&self) -> &str {
        &self.announced
    }

    /// A frame stamped `stamp` went to the gateway.
    pub fn frame_sent(&mut self, stamp: f64) {
        if stamp.is_finite() && self.newest_frame.is_none_or(|s| stamp > s) {
            self.newest_frame = Some(stamp);
        }
    }

    /// Whether the command numbered `seq`, answering the frame stamped
    /// `stamp`, sent for `mission_id` (empty: none) and moving the robot
    /// when `moves`, may drive it; counts it when not.
    pub fn admit(&mut self, seq: u64, stamp: f64, mission_id: &str, moves: bool) -> Result<(), Dropped> {
        let unknown_mission = mission_id != self.announced || (moves && mission_id.is_empty());
        let verdict = match (self.last_seq, self.newest_frame) {
            (Some(last), _) if seq == last => Err(Dropped::Duplicate),
            (Some(last), _) if seq < last => Err(Dropped::OutOfOrder),
            _ if !stamp.is_finite() => Err(Dropped::Unanswerable),
            (_, None) => Err(Dropped::Unanswerable),
            (_, Some(newest)) if stamp > newest + 1e-9 => Err(Dropped::Unanswerable),
            (_, Some(newest)) if newest - stamp > self.deadman_timeout + 1e-9 => Err(Dropped::Stale),
            _ if unknown_mission => Err(Dropped::UnknownMission),
            _ => Ok(()),
        };
        match verdict {
            Ok(()) => self.last_seq = Some(seq),
            Err(Dropped::Duplicate) => self.dropped.duplicate += 1,
            Err(Dropped::OutOfOrder) => self.dropped.out_of_order += 1,
            Err(Dropped::Stale) => self.dropped.stale += 1,
            Err(Dropped::Unanswerable) => self.dropped.unanswerable += 1,
            Err(Dropped::UnknownMission) => self.dropped.unknown_mission += 1,
        }
        verdict
    }

    pub fn dropped(&self) -> DroppedCounts {
        self.dropped
    }
}

/// Turns (possibly stale, possibly wild) velocity commands into what the
/// robot may do at sensor time `now`.
#[derive(Clone, Debug)]
pub struct Governor {
    limits: Limits,
    deadman_timeout: f64,
    estop: bool,
    /// Newest command: its stamp (sensor time of the frame it answers) and twist.
    command: Option<(f64, Twist)>,
    /// Last output and the sensor time it was computed for.
    last: Option<(f64, Twist)>,
}

impl Governor {
    pub fn new(limits: Limits, deadman_timeout_s: f64) -> Self {
        Self { limits, deadman_timeout: deadman_timeout_s.max(0.0), estop: false, command: None, last: None }
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn deadman_timeout(&self) -> f64 {
        self.deadman_timeout
    }

    /// Records a command answering the frame stamped `stamp`. Older commands
    /// than the newest one held are ignored (a reordered or replayed reply).
    pub fn on_command(&mut self, stamp: f64, twist: Twist) {
        if !stamp.is_finite() {
            return;
        }
        if self.command.is_none_or(|(s, _)| stamp >= s) {
            self.command = Some((stamp, twist));
        }
    }

    pub fn set_estop(&mut self, engaged: bool) {
        self.estop = engaged;
    }

    pub fn estop(&self) -> bool {
        self.estop
    }

    /// Forgets the held command (e.g. when the link drops): the robot stops
    /// and stays stopped until a new command arrives.
    pub fn drop_command(&mut self) {
        self.command = None;
    }

    /// The newest command's stamp, if any.
    pub fn command_stamp(&self) -> Option<f64> {
        self.command.map(|(s, _)| s)
    }

    /// The newest command held: its stamp and twist as received.
    pub fn command(&self) -> Option<(f64, Twist)> {
        self.command
    }

    /// Whether a command stamped `stamp` is still within the deadman timeout
    /// at `now` (false for NaN stamps). A nanosecond of slack absorbs float
    /// rounding in summed stamps.
    fn fresh(&self, now: f64, stamp: f64) -> bool {
        now - stamp <= self.deadman_timeout + 1e-9
    }

    /// The velocity to apply at sensor time `now`, and why.
    ///
    /// Stops (zero at once, not ramped: the platform's own controller
    /// brakes) on e-stop, with no command, or when the newest command's stamp
    /// is more than the deadman timeout behind `now`. Otherwise the command
    /// is clamped to the velocity limits and ramped from the previous output
    /// by at most the acceleration limits over the elapsed sensor time.
    pub fn output(&mut self, now: f64) -> (Twist, Verdict) {
        let verdict;
        let out = if self.estop {
            verdict = Verdict::EStop;
            Twist::ZERO
        } else {
            match self.command {
                None => {
                    verdict = Verdict::NoCommand;
                    Twist::ZERO
                }
                Some((stamp, _)) if !self.fresh(now, stamp) => {
                    verdict = Verdict::DeadmanTripped;
                    Twist::ZERO
                }
                Some((_, cmd)) => {
                    let (limited, clamped_v) = clamp_velocity(cmd, &self.limits);
                    let (prev_t, prev) = self.last.unwrap_or((now, Twist::ZERO));
                    let dt = (now - prev_t).max(0.0);
                    let ramped = ramp(prev, limited, &self.limits, dt);
                    verdict = Verdict::Commanded { clamped: clamped_v };
                    ramped
                }
            }
        };
        self.last = Some((now, out));
        (out, verdict)
    }
}

/// Clamps to the velocity limits; non-finite components become zero.
pub fn clamp_velocity(cmd: Twist, l: &Limits) -> (Twist, bool) {
    let f = |v: f64, m: f64| if v.is_finite() { v.clamp(-m, m) } else { 0.0 };
    let out = Twist::new(f(cmd.linear, l.max_linear), f(cmd.angular, l.max_angular));
    (out, out != cmd)
}

/// Moves from `prev` towards `target` by at most the acceleration limits over `dt`.
pub fn ramp(prev: Twist, target: Twist, l: &Limits, dt: f64) -> Twist {
    let step = |p: f64, t: f64, a: f64| p + (t - p).clamp(-a * dt, a * dt);
    Twist::new(
        step(prev.linear, target.linear, l.max_linear_accel),
        step(prev.angular, target.angular, l.max_angular_accel),
    )
}

/// Exponential backoff for reconnecting: `initial`, doubling, capped at `max`;
/// `reset` after a successful connection.
#[derive(Clone, Debug)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    pub fn new(initial: Duration, max: Duration) -> Self {
        Self { initial, max, next: initial }
    }

    /// The delay before the next attempt; doubles the one after.
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }

    pub fn reset(&mut self) {
        self.next = self.initial;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HUSKY: Limits = Limits { max_linear: 1.0, max_angular: 2.0, max_linear_accel: 3.0, max_angular_accel: 6.0 };

    #[test]
    fn no_command_means_stopped() {
        let mut g = Governor::new(HUSKY, 0.3);
        assert_eq!(g.output(1.0), (Twist::ZERO, Verdict::NoCommand));
    }

    #[test]
    fn deadman_trips_once_the_newest_command_is_older_than_the_timeout() {
        let mut g = Governor::new(HUSKY, 0.3);
        g.on_command(10.0, Twist::new(0.2, 0.0));
        let (out, v) = g.output(10.0);
        assert_eq!(v, Verdict::Commanded { clamped: false });
        assert_eq!(out, Twist::new(0.0, 0.0), "first output ramps from rest over zero elapsed time");
        let (out, _) = g.output(10.1);
        assert!((out.linear - 0.2).abs() < 1e-12);
        assert_eq!(g.output(10.3).1, Verdict::Commanded { clamped: false }, "exactly at the timeout still fresh");
        let (out, v) = g.output(10.3001);
        assert_eq!((out, v), (Twist::ZERO, Verdict::DeadmanTripped));
        assert!(v.deadman_tripped());
        // A fresh command revives it; ramping restarts from the zero just sent.
        g.on_command(10.4, Twist::new(1.0, 0.0));
        let (out, _) = g.output(10.45);
        assert!((out.linear - 3.0 * (10.45 - 10.3001)).abs() < 1e-9, "{out:?}");
    }

    #[test]
    fn stale_replies_do_not_replace_a_newer_command() {
        let mut g = Governor::new(HUSKY, 0.3);
        g.on_command(5.0, Twist::new(0.5, 0.0));
        g.on_command(4.0, Twist::new(-1.0, 0.0));
        assert_eq!(g.command_stamp(), Some(5.0));
        g.on_command(f64::NAN, Twist::new(-1.0, 0.0));
        assert_eq!(g.command_stamp(), Some(5.0));
    }

    #[test]
    fn commands_above_the_limits_are_clamped_and_ramped() {
        let mut g = Governor::new(HUSKY, 0.3);
        g.on_command(0.0, Twist::new(5.0, -9.0));
        g.output(0.0);
        let mut prev = Twist::ZERO;
        for k in 1..=20 {
            let t = k as f64 * 0.1;
            g.on_command(t, Twist::new(5.0, -9.0));
            let (out, v) = g.output(t);
            assert!(matches!(v, Verdict::Commanded { clamped: true }));
            assert!(out.linear <= 1.0 && out.angular >= -2.0);
            assert!(
                (out.linear - prev.linear).abs() <= 0.3 + 1e-12 && (out.angular - prev.angular).abs() <= 0.6 + 1e-12
            );
            prev = out;
        }
        assert_eq!(prev, Twist::new(1.0, -2.0));
        assert_eq!(clamp_velocity(Twist::new(f64::INFINITY, f64::NAN), &HUSKY).0, Twist::ZERO);
    }

    #[test]
    fn estop_overrides_everything_until_released() {
        let mut g = Governor::new(HUSKY, 0.3);
        g.on_command(1.0, Twist::new(0.5, 0.0));
        g.output(1.0);
        g.set_estop(true);
        assert_eq!(g.output(1.1), (Twist::ZERO, Verdict::EStop));
        g.on_command(1.2, Twist::new(0.5, 0.0));
        assert_eq!(g.output(1.2), (Twist::ZERO, Verdict::EStop));
        g.set_estop(false);
        let (out, v) = g.output(1.3);
        assert_eq!(v, Verdict::Commanded { clamped: false });
        assert!((out.linear - 0.3).abs() < 1e-12, "ramps up again from the stop: {out:?}");
    }

    #[test]
    fn dropping_the_link_drops_the_command() {
        let mut g = Governor::new(HUSKY, 0.3);
        g.on_command(1.0, Twist::new(0.5, 0.0));
        g.drop_command();
        assert_eq!(g.output(1.05).1, Verdict::NoCommand);
    }

    #[test]
    fn backoff_doubles_up_to_its_cap_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(700));
        let ms: Vec<u128> = (0..5).map(|_| b.next_delay().as_millis()).collect();
        assert_eq!(ms, vec![100, 200, 400, 700, 700]);
        b.reset();
        assert_eq!(b.next_delay(), Duration::from_millis(100));
    }

    #[test]
    fn replayed_reordered_stale_and_unanswerable_commands_are_dropped_and_counted() {
        let mut gate = CommandGate::new(0.3);
        gate.announce("m-1");
        assert_eq!(gate.admit(1, 0.0, "m-1", true), Err(Dropped::Unanswerable), "no frame sent yet");
        gate.frame_sent(0.1);
        assert_eq!(gate.admit(1, 0.1, "m-1", true), Ok(()));
        assert_eq!(gate.admit(1, 0.1, "m-1", true), Err(Dropped::Duplicate));
        gate.frame_sent(0.2);
        assert_eq!(gate.admit(3, 0.2, "m-1", true), Ok(()));
        assert_eq!(gate.admit(2, 0.1, "m-1", true), Err(Dropped::OutOfOrder));
        assert_eq!(gate.admit(4, 0.5, "m-1", true), Err(Dropped::Unanswerable), "answers a frame never sent");
        gate.frame_sent(1.0);
        assert_eq!(gate.admit(5, 0.6, "m-1", true), Err(Dropped::Stale));
        assert_eq!(gate.admit(6, f64::NAN, "m-1", true), Err(Dropped::Unanswerable));
        assert_eq!(gate.admit(7, 0.9, "m-1", true), Ok(()));
        let d = gate.dropped();
        assert_eq!((d.duplicate, d.out_of_order, d.stale, d.unanswerable), (1, 1, 1, 3));
        assert_eq!(d.total(), 6);
    }

    #[test]
    fn a_robot_fed_only_replays_stays_stopped() {
        let mut gate = CommandGate::new(0.3);
        let mut gov = Governor::new(HUSKY, 0.3);
        gate.announce("m-1");
        gate.frame_sent(0.0);
        gate.admit(10, 0.0, "m-1", true).unwrap();
        gov.on_command(0.0, Twist::new(1.0, 0.0));
        // The attacker replays the one command it captured at every frame.
        for k in 1..20 {
            let now = k as f64 * 0.1;
            gate.frame_sent(now);
            if gate.admit(10, 0.0, "m-1", true).is_ok() {
                gov.on_command(0.0, Twist::new(1.0, 0.0));
            }
            let (out, verdict) = gov.output(now);
            if now > 0.3 + 1e-9 {
                assert_eq!(out, Twist::ZERO, "at {now}");
                assert_eq!(verdict, Verdict::DeadmanTripped);
            }
        }
        assert_eq!(gate.dropped().duplicate, 19);
    }

    #[test]
    fn commands_outside_the_announced_mission_are_dropped_and_counted() {
        let mut gate = CommandGate::new(0.3);
        gate.frame_sent(0.1);
        // Nothing announced: an idle stop passes, anything that moves does not.
        assert_eq!(gate.admit(1, 0.1, "", false), Ok(()));
        assert_eq!(gate.admit(2, 0.1, "", true), Err(Dropped::UnknownMission));
        assert_eq!(gate.admit(3, 0.1, "m-1", true), Err(Dropped::UnknownMission), "never announced");
        gate.announce("m-1");
        assert_eq!(gate.announced(), "m-1");
        assert_eq!(gate.admit(4, 0.1, "m-1", true), Ok(()));
        assert_eq!(gate.admit(5, 0.1, "m-2", true), Err(Dropped::UnknownMission), "another mission");
        assert_eq!(gate.admit(6, 0.1, "", false), Err(Dropped::UnknownMission), "the mission has not ended");
        // The mission ends: its own commands no longer drive.
        gate.announce("");
        assert_eq!(gate.admit(7, 0.1, "m-1", true), Err(Dropped::UnknownMission));
        assert_eq!(gate.admit(8, 0.1, "", false), Ok(()));
        assert_eq!(gate.dropped().unknown_mission, 5);
        assert_eq!(gate.dropped().total(), 5);
    }
}
