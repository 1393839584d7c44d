//! A robot's inbound stream: every message an edge agent sends on Attach
//! enters the gateway here. Depth is decoded and each frame checked once,
//! into a [`CheckedFrame`] (`frames.rs`), before it is handed to the robot's
//! actor (`robot.rs`), which answers on the outbound stream. A refused
//! message closes the stream with a status saying why.

use tonic::{Status, Streaming};
use vlnav_proto::v1::{EdgeMessage, edge_message};
use vlnav_runtime::actor::Mailbox;

use crate::frames::{self, CheckedFrame, FrameError};
use crate::robot::{Outbound, RobotMsg};

/// Reads robot `robot`'s connection `conn` until it ends, telling its actor
/// (`mailbox`) each message and, at the end, why it detached.
pub(crate) fn spawn(
    mut inbound: Streaming<EdgeMessage>,
    robot: String,
    conn: u64,
    mailbox: Mailbox<RobotMsg>,
    tx: Outbound,
) {
    tokio::spawn(async move {
        let mut last_stamp = None;
        let reason = loop {
            let msg = match inbound.message().await {
                Ok(Some(m)) => m,
                Ok(None) => break "the edge agent closed the stream".to_string(),
                Err(s) => {
                    let status = if s.code() == tonic::Code::OutOfRange && s.message().contains("too large") {
                        Status::resource_exhausted(format!(
                            "robot '{robot}': a message exceeded the gateway's size limit ({}); lower the camera \
                             resolution or raise VLNAV_MAX_MESSAGE_BYTES on the gateway",
                            s.message()
                        ))
                    } else {
                        s
                    };
                    let reason = format!("stream error: {}", status.message());
                    let _ = tx.send(Err(status)).await;
                    break reason;
                }
            };
            let sent = match msg.kind {
                Some(edge_message::Kind::Frame(mut frame)) => {
                    // Decoding RVL depth takes a millisecond or more: off the async workers.
                    let mut decoded = Ok(());
                    if let Some(mut f) = frame.frame.take() {
                        if frames::is_encoded(&f) {
                            let job = tokio::task::spawn_blocking(move || {
                                let r = frames::decode_depth(&mut f);
                                (f, r)
                            });
                            match job.await {
                                Ok((back, r)) => {
                                    f = back;
                                    decoded = r;
                                }
                                Err(e) => {
                                    let status =
                                        Status::internal(format!("robot '{robot}': the depth decoder failed: {e}"));
                                    let _ = tx.send(Err(status)).await;
                                    break format!("depth decoder failed: {e}");
                                }
                            }
                        }
                        frame.frame = Some(f);
                    }
                    let foreign =
                        frame.frame.as_ref().filter(|f| !f.robot_id.is_empty() && f.robot_id != robot).map(|f| {
                            FrameError::Invalid {
                                seq: f.seq,
                                what: format!("robot_id '{}' differs from the attached robot", f.robot_id),
                            }
                        });
                    let checked = match foreign {
                        Some(e) => Err(e),
                        None => decoded.and_then(|()| CheckedFrame::check(frame, last_stamp)),
                    };
                    match checked {
                        Ok(frame) => {
                            last_stamp = Some(frame.frame().stamp);
                            mailbox.tell(RobotMsg::Frame { conn, frame: Box::new(frame) }).await
                        }
                        Err(e) => {
                            tracing::warn!(robot = %robot, "rejected frame: {e}");
                            let _ = tx.send(Err(frame_status(&robot, &e))).await;
                            break format!("invalid frame: {e}");
                        }
                    }
                }
                Some(edge_message::Kind::Odometry(o)) => {
                    if let Some(p) = &o.pose
                        && let Err(e) = frames::check_pose(0, p)
                    {
                        let _ = tx.send(Err(frame_status(&robot, &e))).await;
                        break format!("invalid odometry: {e}");
                    }
                    mailbox.tell(RobotMsg::Odometry { conn, odometry: o }).await
                }
                Some(edge_message::Kind::Status(s)) => mailbox.tell(RobotMsg::Status { conn, status: s }).await,
                Some(edge_message::Kind::Hello(_)) => {
                    let _ = tx.send(Err(Status::invalid_argument("EdgeHello may only be sent once, first"))).await;
                    break "a second hello".to_string();
                }
                None => Ok(()),
            };
            if sent.is_err() {
                let _ = tx.send(Err(Status::unavailable("the robot's actor stopped; reconnect"))).await;
                break "the robot actor stopped".to_string();
            }
        };
        let _ = mailbox.tell(RobotMsg::Detach { conn, reason }).await;
    });
}

fn frame_status(robot: &str, e: &FrameError) -> Status {
    Status::invalid_argument(format!("robot '{robot}', {e}; the stream is closed and the robot is held stopped"))
}
