//! Writing a run file off the step's critical path: a [`RunWriter`] on its own thread, fed
//! frame by frame through a bounded queue (back-pressure: at most two frames and two states in
//! flight), and [`RunSink`], what an observer of a run writes to (either writer).

use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use moreau_core::StepReport;

use crate::error::IoError;
use crate::layout::{ContactRow, StepRow};
use crate::writer::RunWriter;

/// What a run's observer writes: steps, exits, people entering, contact forces, frames and
/// saved states, in the order they happen. [`RunWriter`] writes them at once; [`BackgroundWriter`] on its own
/// thread.
pub trait RunSink: Send {
    /// Records a step (written with the next frame).
    fn step(&mut self, report: &StepReport);
    /// Records that person `id` passed exit `exit` (its index in the scene) at time `t`.
    fn exit(&mut self, id: u32, exit: u32, t: f64) -> Result<(), IoError>;
    /// Records that person `id` of radius `radius` and group `group` (the scene's groups, then
    /// one per source) entered at time `t` (ids in order, each the next).
    fn enter(&mut self, id: u32, radius: f64, t: f64, group: u32) -> Result<(), IoError>;
    /// Whether the file records contact forces.
    fn records_contacts(&self) -> bool;
    /// The contact forces of the next frame and the pressure by id.
    fn contact_rows(
        &mut self,
        rows: &mut dyn Iterator<Item = ContactRow>,
        pressure_by_id: &[f64],
    ) -> Result<(), IoError>;
    /// The segments of the moving bodies at the next frame.
    fn moving_walls(&mut self, segments: &[[f64; 4]]) -> Result<(), IoError>;
    /// One output frame.
    fn frame(&mut self, t: f64, ids: &[u32], positions: &[f64]) -> Result<(), IoError>;
    /// The run's state after the last frame (its bytes, handed over: a writer on another
    /// thread keeps them without a copy).
    fn save_state(&mut self, bytes: Vec<u8>) -> Result<(), IoError> {
        self.save_state_noted(bytes, String::new())
    }
    /// [`RunWriter::save_state_noted`].
    fn save_state_noted(&mut self, bytes: Vec<u8>, note: String) -> Result<(), IoError>;
}

impl RunSink for RunWriter {
    fn step(&mut self, report: &StepReport) {
        RunWriter::step(self, report);
    }
    fn exit(&mut self, id: u32, exit: u32, t: f64) -> Result<(), IoError> {
        RunWriter::exit(self, id, exit, t)
    }
    fn enter(&mut self, id: u32, radius: f64, t: f64, group: u32) -> Result<(), IoError> {
        RunWriter::enter(self, id, radius, t, group)
    }
    fn records_contacts(&self) -> bool {
        RunWriter::records_contacts(self)
    }
    fn contact_rows(
        &mut self,
        rows: &mut dyn Iterator<Item = ContactRow>,
        pressure_by_id: &[f64],
    ) -> Result<(), IoError> {
        RunWriter::contacts(self, rows, pressure_by_id)
    }
    fn moving_walls(&mut self, segments: &[[f64; 4]]) -> Result<(), IoError> {
        RunWriter::moving_walls(self, segments)
    }
    fn frame(&mut self, t: f64, ids: &[u32], positions: &[f64]) -> Result<(), IoError> {
        RunWriter::frame(self, t, ids, positions)
    }
    fn save_state_noted(&mut self, bytes: Vec<u8>, note: String) -> Result<(), IoError> {
        RunWriter::save_state_noted(self, &bytes, &note)
    }
}

/// Everything between two frames, and the frame.
#[derive(Debug, Default)]
struct Batch {
    steps: Vec<StepRow>,
    /// Who entered, with their radii and times, in order.
    entries: Vec<(u32, f64, f64, u32)>,
    exits: Vec<(u32, u32, f64)>,
    contacts: Option<(Vec<ContactRow>, Vec<f64>)>,
    moving: Option<Vec<[f64; 4]>>,
    t: f64,
    ids: Vec<u32>,
    positions: Vec<f64>,
}

enum Message {
    Frame(Box<Batch>),
    State(Vec<u8>, String),
    Finish {
        steps: Vec<StepRow>,
        entries: Vec<(u32, f64, f64, u32)>,
        exits: Vec<(u32, u32, f64)>,
        status: String,
        summary: String,
    },
}

/// A [`RunWriter`] on its own thread. A write that fails there is reported by the next
/// [`RunSink::frame`] or [`RunSink::save_state`] (the run stops one frame later than with a
/// writer in the stepping thread, and the file keeps its whole frames as ever) and by
/// [`finish`](Self::finish).
#[derive(Debug)]
pub struct BackgroundWriter {
    queue: Option<SyncSender<Message>>,
    thread: Option<JoinHandle<Result<(), IoError>>>,
    failed: Arc<Mutex<Option<IoError>>>,
    pending: Batch,
    contacts: bool,
    /// People the file holds, those who entered included (ids `0..people`).
    people: usize,
    path: std::path::PathBuf,
}

impl BackgroundWriter {
    /// Moves `writer` to a thread of its own.
    pub fn new(writer: RunWriter) -> Self {
        let (queue, inbox) = sync_channel(2);
        let failed = Arc::new(Mutex::new(None));
        let contacts = writer.records_contacts();
        let people = writer.people();
        let path = writer.path().to_path_buf();
        let shared = Arc::clone(&failed);
        let thread = std::thread::Builder::new()
            .name("moreau-writer".into())
            .spawn(move || work(writer, inbox, shared))
            .expect("a thread for the run file");
        Self {
            queue: Some(queue),
            thread: Some(thread),
            failed,
            pending: Batch::default(),
            contacts,
            people,
            path,
        }
    }

    /// The first error of the writing thread, if there was one (taken).
    fn take_failure(&self) -> Option<IoError> {
        self.failed.lock().ok().and_then(|mut f| f.take())
    }

    fn send(&mut self, message: Message) -> Result<(), IoError> {
        if let Some(e) = self.take_failure() {
            return Err(e);
        }
        let sent = self.queue.as_ref().map(|q| q.send(message));
        match sent {
            Some(Ok(())) => Ok(()),
            // The thread ended (it panicked): its error, or say so.
            _ => {
                let path = self.path.clone();
                Err(self.join().err().unwrap_or(IoError::Layout {
                    path,
                    what: "the run file's writing thread ended early".into(),
                }))
            }
        }
    }

    fn join(&mut self) -> Result<(), IoError> {
        self.queue = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(IoError::Layout {
                path: self.path.clone(),
                what: "the run file's writing thread panicked".into(),
            }),
            None => Ok(()),
        }
    }

    /// Ends the run as [`RunWriter::finish`] does, once every frame sent is written; the first
    /// error of the whole writing is returned.
    pub fn finish(mut self, status: &str, summary: &str) -> Result<(), IoError> {
        let earlier = self.take_failure();
        let message = Message::Finish {
            steps: std::mem::take(&mut self.pending.steps),
            entries: std::mem::take(&mut self.pending.entries),
            exits: std::mem::take(&mut self.pending.exits),
            status: status.to_string(),
            summary: summary.to_string(),
        };
        let sent = self.queue.as_ref().map(|q| q.send(message));
        let joined = self.join();
        let later = self.take_failure();
        match (earlier, sent, joined, later) {
            (Some(e), ..) => Err(e),
            (None, _, Err(e), _) => Err(e),
            (None, _, Ok(()), Some(e)) => Err(e),
            _ => Ok(()),
        }
    }
}

impl Drop for BackgroundWriter {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// The writing thread: writes each message in order; after a failure it keeps the first
/// error for the stepping thread and only finishes the file.
fn work(
    mut writer: RunWriter,
    inbox: Receiver<Message>,
    failed: Arc<Mutex<Option<IoError>>>,
) -> Result<(), IoError> {
    let mut broken = false;
    let fail = |e: IoError, broken: &mut bool| {
        *broken = true;
        if let Ok(mut f) = failed.lock() {
            f.get_or_insert(e);
        }
    };
    for message in inbox {
        match message {
            Message::Frame(batch) if !broken => {
                if let Err(e) = write_batch(&mut writer, *batch) {
                    fail(e, &mut broken);
                }
            }
            Message::State(bytes, note) if !broken => {
                if let Err(e) = writer.save_state_noted(&bytes, &note) {
                    fail(e, &mut broken);
                }
            }
            Message::Finish {
                steps,
                entries,
                exits,
                status,
                summary,
            } => {
                for s in steps {
                    writer.step_row(s);
                }
                for (id, radius, t, group) in entries {
                    let _ = writer.enter(id, radius, t, group);
                }
                for (id, exit, t) in exits {
                    let _ = writer.exit(id, exit, t);
                }
                return writer.finish(&status, &summary);
            }
            _ => {}
        }
    }
    // The stepping side went away without finishing (it panicked): leave the partial file.
    Ok(())
}

fn write_batch(writer: &mut RunWriter, batch: Batch) -> Result<(), IoError> {
    for s in batch.steps {
        writer.step_row(s);
    }
    // Everyone who entered before anyone's exit: a newcomer may leave in the same batch.
    for (id, radius, t, group) in batch.entries {
        writer.enter(id, radius, t, group)?;
    }
    for (id, exit, t) in batch.exits {
        writer.exit(id, exit, t)?;
    }
    if let Some((rows, pressure)) = batch.contacts {
        writer.contacts(rows, &pressure)?;
    }
    if let Some(segments) = &batch.moving {
        writer.moving_walls(segments)?;
    }
    writer.frame(batch.t, &batch.ids, &batch.positions)
}

impl RunSink for BackgroundWriter {
    fn step(&mut self, report: &StepReport) {
        self.pending.steps.push(StepRow::from(report));
    }
    fn exit(&mut self, id: u32, exit: u32, t: f64) -> Result<(), IoError> {
        if id as usize >= self.people {
            return Err(IoError::Layout {
                path: self.path.clone(),
                what: format!(
                    "exit of person {id}, but the file holds {} people",
                    self.people
                ),
            });
        }
        self.pending.exits.push((id, exit, t));
        Ok(())
    }
    fn enter(&mut self, id: u32, radius: f64, t: f64, group: u32) -> Result<(), IoError> {
        if id as usize != self.people {
            return Err(IoError::Layout {
                path: self.path.clone(),
                what: format!(
                    "person {id} entered, but the next id is {} (people enter in order of id)",
                    self.people
                ),
            });
        }
        self.people += 1;
        self.pending.entries.push((id, radius, t, group));
        Ok(())
    }
    fn records_contacts(&self) -> bool {
        self.contacts
    }
    fn contact_rows(
        &mut self,
        rows: &mut dyn Iterator<Item = ContactRow>,
        pressure_by_id: &[f64],
    ) -> Result<(), IoError> {
        if self.contacts {
            self.pending.contacts = Some((rows.collect(), pressure_by_id.to_vec()));
        }
        Ok(())
    }
    fn moving_walls(&mut self, segments: &[[f64; 4]]) -> Result<(), IoError> {
        self.pending.moving = Some(segments.to_vec());
        Ok(())
    }
    fn frame(&mut self, t: f64, ids: &[u32], positions: &[f64]) -> Result<(), IoError> {
        let mut batch = std::mem::take(&mut self.pending);
        batch.t = t;
        batch.ids = ids.to_vec();
        batch.positions = positions.to_vec();
        self.send(Message::Frame(Box::new(batch)))
    }
    fn save_state_noted(&mut self, bytes: Vec<u8>, note: String) -> Result<(), IoError> {
        // Between frames only, as `RunWriter::save_state` says: the steps batched here would
        // otherwise reach the file after a state that does not count them (this writer let
        // it pass while the frame at a horizon off the output times went unwritten).
        let pending = &self.pending;
        if !pending.steps.is_empty() || !pending.exits.is_empty() || !pending.entries.is_empty() {
            return Err(IoError::Layout {
                path: self.path.clone(),
                what: format!(
                    "a state saved between frames ({} steps, {} exits, {} people not yet \
                     written)",
                    pending.steps.len(),
                    pending.exits.len(),
                    pending.entries.len()
                ),
            });
        }
        self.send(Message::State(bytes, note))
    }
}
