//! Writing a run file as the run goes: buffered between output frames, flushed at each;
//! under a temporary name until the run ends, and only then moved to its name.

use std::fs::OpenOptions;
use std::path::{Path, PathBuf};

use hdf5::types::VarLenUnicode;
use hdf5::{Dataset, File, H5Type};
use moreau_core::{Num, StepReport};
use ndarray::ArrayView2;

use crate::error::{Context, IoError};
use crate::layout::*;

/// Whether an existing output file may be replaced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overwrite {
    /// Refuse: [`IoError::Exists`].
    Never,
    /// Replace it (the user asked, `--force`).
    Allowed,
}

/// The temporary name a run file is written under until its run ends: `.NAME.partial` in the
/// output's directory. A run killed by SIGKILL (or a power cut) leaves its frames there, with
/// `status = running`; `moreau inspect`, h5py and PedPy open it.
pub fn partial_path(path: &Path) -> PathBuf {
    hidden_sibling(path, "partial")
}

/// The lock file of an output: `.NAME.lock`, held (`flock`) by the one writer of `path`.
pub fn lock_path(path: &Path) -> PathBuf {
    hidden_sibling(path, "lock")
}

fn hidden_sibling(path: &Path, suffix: &str) -> PathBuf {
    let name = path
        .file_name()
        .map_or("run".into(), |n| n.to_string_lossy());
    path.with_file_name(format!(".{name}.{suffix}"))
}

/// The exclusive right to write one output path, held for the life of its writer: the second
/// writer of a path is refused ([`IoError::Busy`]) instead of silently replacing the first's
/// file. An advisory `flock` on `.NAME.lock`, released by the system when the process dies
/// however it dies; the file itself is removed when the writer ends.
#[derive(Debug)]
struct OutputLock {
    path: PathBuf,
    file: std::fs::File,
}

impl OutputLock {
    fn acquire(output: &Path) -> Result<Self, IoError> {
        use std::os::unix::fs::MetadataExt;
        let path = lock_path(output);
        let failed = |e: std::io::Error| IoError::Create {
            path: output.to_path_buf(),
            reason: format!("cannot take its lock file '{}': {e}", path.display()),
        };
        // A holder removes the lock file before releasing it: a lock taken on a file that is
        // no longer at `path` locks nothing, so take it again.
        for _ in 0..16 {
            let file = OpenOptions::new()
                .create(true)
                .truncate(false)
                .write(true)
                .open(&path)
                .map_err(failed)?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    return Err(IoError::Busy {
                        path: output.to_path_buf(),
                        lock: path,
                    });
                }
                Err(std::fs::TryLockError::Error(e)) => return Err(failed(e)),
            }
            let same = match (file.metadata(), std::fs::metadata(&path)) {
                (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
                _ => false,
            };
            if same {
                return Ok(Self { path, file });
            }
        }
        Err(IoError::Busy {
            path: output.to_path_buf(),
            lock: path,
        })
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while held, then released (closing the file releases the lock).
        let _ = std::fs::remove_file(&self.path);
        let _ = self.file.unlock();
    }
}

/// Where writing a run file fails on purpose, for tests of what a failure leaves (a full disk
/// in the middle of a frame): the `dataset` of frame `frame` (`people/id`, `people/radius`,
/// `trajectory`, `frames/positions`, `frames/time`, `frames/count`, `contacts`,
/// `frames/pressure`, `steps`, `exits`, `flush`).
#[doc(hidden)]
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FailPoint {
    /// The frame (from 0).
    pub frame: usize,
    /// The dataset, or `flush`.
    pub dataset: String,
}

/// What [`RunWriter::resume`] gives back.
#[derive(Debug)]
pub struct Resumed {
    /// The writer, where the saved state left the file.
    pub writer: RunWriter,
    /// The header the run was started with (its scene, above all).
    pub header: RunHeader,
    /// The saved state's bytes.
    pub state: Vec<u8>,
    /// The text saved with them ([`RunWriter::save_state_noted`]; empty for a state saved
    /// without, and in files written before 2026-11-28).
    pub note: String,
}

/// Where the datasets stood when a state was saved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct StateMarks {
    people: usize,
    frames: usize,
    steps: usize,
    exits: usize,
    trajectory_rows: usize,
    contact_rows: usize,
}

/// `/state`: two byte slots written in turn, and the group's attributes saying which one is
/// whole (`slot`: 1 or 2, 0 before the first) and where the datasets stood. A slot is written
/// while the attributes on disk still name the other one, so a kill at any moment leaves a
/// whole state.
#[derive(Debug)]
struct StateSlots {
    group: hdf5::Group,
    slots: [Dataset; 2],
    slot: u8,
}

const STATE_MARKS: [&str; 6] = [
    "people",
    "frames",
    "steps",
    "exits",
    "trajectory_rows",
    "contact_rows",
];

impl StateSlots {
    fn create(file: &File) -> hdf5::Result<Self> {
        let group = file.create_group(STATE)?;
        let slot = |name: &str| {
            group
                .new_dataset::<u8>()
                .chunk(STATE_BYTES_PER_CHUNK)
                .shape(0..)
                .create(name)
        };
        let slots = [slot("a")?, slot("b")?];
        group
            .new_attr::<u8>()
            .shape(())
            .create("slot")?
            .write_scalar(&0u8)?;
        for name in STATE_MARKS {
            group
                .new_attr::<u64>()
                .shape(())
                .create(name)?
                .write_scalar(&0u64)?;
        }
        Ok(Self {
            group,
            slots,
            slot: 0,
        })
    }

    fn open(file: &File) -> hdf5::Result<Self> {
        let group = file.group(STATE)?;
        let slots = [group.dataset("a")?, group.dataset("b")?];
        let slot = group.attr("slot")?.read_scalar::<u8>()?;
        Ok(Self { group, slots, slot })
    }

    fn save(&mut self, bytes: &[u8], marks: StateMarks, note: &str) -> hdf5::Result<()> {
        let next = if self.slot == 1 { 2 } else { 1 };
        let ds = &self.slots[usize::from(next - 1)];
        ds.resize(bytes.len())?;
        if !bytes.is_empty() {
            ds.write_slice(bytes, 0..bytes.len())?;
        }
        set_text(ds, "note", note)?;
        let values = [
            marks.people,
            marks.frames,
            marks.steps,
            marks.exits,
            marks.trajectory_rows,
            marks.contact_rows,
        ];
        for (name, value) in STATE_MARKS.iter().zip(values) {
            self.group.attr(name)?.write_scalar(&(value as u64))?;
        }
        self.group.attr("slot")?.write_scalar(&next)?;
        self.slot = next;
        Ok(())
    }

    fn load(&self) -> hdf5::Result<(Vec<u8>, Option<StateMarks>, String)> {
        if self.slot == 0 {
            return Ok((Vec::new(), None, String::new()));
        }
        let ds = &self.slots[usize::from(self.slot - 1).min(1)];
        let bytes = ds.read_raw::<u8>()?;
        let note = match ds.attr("note") {
            Ok(a) => a.read_scalar::<VarLenUnicode>()?.as_str().to_string(),
            Err(_) => String::new(),
        };
        let mut v = [0usize; 6];
        for (k, name) in STATE_MARKS.iter().enumerate() {
            v[k] = self.group.attr(name)?.read_scalar::<u64>()? as usize;
        }
        Ok((
            bytes,
            Some(StateMarks {
                people: v[0],
                frames: v[1],
                steps: v[2],
                exits: v[3],
                trajectory_rows: v[4],
                contact_rows: v[5],
            }),
            note,
        ))
    }
}

/// A person who entered since the last frame: their `people/*` rows to come.
#[derive(Debug, Clone, Copy)]
struct Newcomer {
    radius: f64,
    t: f64,
    group: i64,
}

/// Writes one run file. Rows given between two frames are held in memory and written with
/// the next frame, then the file is flushed: on disk the file is always a whole number of
/// frames, whatever moment the process dies, and a frame whose writing fails (a full disk) is
/// taken back from every dataset. The file is written under a temporary name
/// ([`partial_path`]) and moved to its name by [`finish`](Self::finish) only.
#[derive(Debug)]
pub struct RunWriter {
    path: PathBuf,
    partial: PathBuf,
    overwrite: Overwrite,
    lock: Option<OutputLock>,
    fail: Option<FailPoint>,
    file: File,
    people_id: Dataset,
    people_radius: Dataset,
    people_entry: Dataset,
    people_group: Dataset,
    trajectory: Dataset,
    frame_time: Dataset,
    frame_count: Dataset,
    positions: Dataset,
    exits: Dataset,
    steps: Dataset,
    /// `/contacts` and `/frames/pressure`, when the run records contact forces.
    contacts: Option<(Dataset, Dataset)>,
    /// `/frames/moving_walls`, when the scene has moving bodies.
    moving: Option<Dataset>,
    /// Segments of the moving bodies.
    moving_segments: usize,
    /// `/state` and its two slots.
    state: StateSlots,
    /// People in the whole frames written (ids `0..people`).
    people: usize,
    /// The people who entered since the last frame (ids `people..`).
    pending_people: Vec<Newcomer>,
    frames: usize,
    /// `trajectory.fps`: a frame's row in `/trajectory` is numbered `t × fps`.
    fps: f64,
    trajectory_rows: usize,
    exit_rows: usize,
    step_rows: usize,
    contact_rows: usize,
    exit_times: Vec<f64>,
    pending_steps: Vec<StepRow>,
    pending_exits: Vec<ExitRow>,
    rows: Vec<TrajectoryRow>,
    dense: Vec<f64>,
    pending_contacts: Vec<ContactRow>,
    pending_pressure: Vec<f64>,
    pending_moving: Vec<f64>,
}

/// The number of the frame at time `t` in `/trajectory`, where PedPy reads its time as
/// `frame / fps`: `t × fps` rounded, or `None` for a frame off that grid (the horizon's, where
/// no output time reaches it: it is in `/frames` only). Until session 38 rows were numbered
/// by the frames written, so such a frame at 2.05 s, after 2.0 s at 10 fps, read as 2.1 s.
fn trajectory_frame(t: f64, fps: f64) -> Option<i64> {
    let x = t * fps;
    let k = x.round();
    ((x - k).abs() <= 1e-6).then_some(k as i64)
}

fn text(s: &str) -> VarLenUnicode {
    // Interior NULs cannot be stored in an HDF5 string; nothing we write has one.
    s.replace('\0', "").parse().expect("no NUL left")
}

fn set_text(loc: &hdf5::Location, name: &str, value: &str) -> hdf5::Result<()> {
    if loc.attr_names()?.iter().any(|n| n == name) {
        loc.delete_attr(name)?;
    }
    loc.new_attr::<VarLenUnicode>()
        .shape(())
        .create(name)?
        .write_scalar(&text(value))
}

/// Opens an HDF5 file without HDF5's own file locking: readers (`moreau inspect`, h5py) open a
/// run file while its run writes it (every frame is flushed whole), and writers exclude each
/// other through [`OutputLock`].
pub(crate) fn without_locking() -> hdf5::FileBuilder {
    let mut b = File::with_options();
    b.with_fapl(|p| p.file_locking(false));
    b
}

/// Whether `path` is a run file finished with status `interrupted` (a run stopped by a signal).
fn interrupted(path: &Path) -> bool {
    path.is_file()
        && crate::RunFile::open(path)
            .and_then(|f| f.text("status"))
            .is_ok_and(|s| s == "interrupted")
}

// The one foreign call of this crate: the `hdf5` crate does not bind it.
#[allow(unsafe_code)]
unsafe extern "C" {
    /// HDF5 ≥ 1.10 (`H5Fpublic.h`): sets the file's end of allocation to the larger of it and
    /// the end of the file, plus `increment` (what `h5clear --increment` does).
    fn H5Fincrement_filesize(file_id: i64, increment: u64) -> std::ffi::c_int;
}

/// A run killed while HDF5 flushed can leave a chunk written past the end of allocation the
/// superblock records ("addr overflow … eoa" on reading the last frame, and a resume's first
/// flush failed, moving the file to its name as failed and unresumable): the end of
/// allocation is moved to the end of the file, as `h5clear --increment 0` would. A file
/// whose end of allocation is already there is left as it is.
#[allow(unsafe_code)]
fn end_of_allocation_at_end_of_file(file: &File) {
    // SAFETY: `file` is an open file identifier; the call only moves its end of allocation,
    // under the library's lock as every call of the `hdf5` crate.
    let _ = hdf5::sync::sync(|| unsafe { H5Fincrement_filesize(file.id(), 0) });
}

/// Whether two paths name the same file; for a path that does not exist yet, whether its
/// directory and name are the other's.
pub fn same_file(a: &Path, b: &Path) -> bool {
    fn resolved(p: &Path) -> Option<PathBuf> {
        if let Ok(c) = p.canonicalize() {
            return Some(c);
        }
        let parent = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        Some(parent.canonicalize().ok()?.join(p.file_name()?))
    }
    match (resolved(a), resolved(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

/// Checks that `path` can be created, before anything is made: the parent is a directory
/// that exists, the path is not a directory, and an existing file is replaced only if asked.
pub fn check_output(path: &Path, overwrite: Overwrite) -> Result<(), IoError> {
    let create = |reason: String| IoError::Create {
        path: path.to_path_buf(),
        reason,
    };
    if path.as_os_str().is_empty() {
        return Err(create("the path is empty".into()));
    }
    if path.is_dir() {
        return Err(create("it is a directory".into()));
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        return Err(create(format!(
            "the directory '{}' does not exist",
            parent.display()
        )));
    }
    if path.exists() {
        if overwrite == Overwrite::Never {
            return Err(IoError::Exists {
                path: path.to_path_buf(),
            });
        }
        if !path.is_file() {
            return Err(create("it exists and is not a regular file".into()));
        }
    }
    Ok(())
}

impl RunWriter {
    /// Creates the file, its datasets and its attributes, and flushes it (status `running`),
    /// under the temporary name [`partial_path`] in the output's directory: `path` itself is
    /// not touched until [`finish`](Self::finish) moves the file there, so an existing file
    /// (with [`Overwrite::Allowed`]) stays whole until the new run ends. A second writer of
    /// the same path is refused ([`IoError::Busy`]); a partial file left by a killed run is
    /// replaced only with [`Overwrite::Allowed`] ([`IoError::Stale`]). Nothing is left behind
    /// when this fails.
    pub fn create(path: &Path, header: &RunHeader, overwrite: Overwrite) -> Result<Self, IoError> {
        check_output(path, overwrite)?;
        if !(header.fps > 0.0 && header.fps.is_finite()) {
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: format!("fps must be > 0 and finite, got {}", header.fps),
            });
        }
        let lock = OutputLock::acquire(path)?;
        let partial = partial_path(path);
        if partial.exists() {
            if overwrite == Overwrite::Never {
                return Err(IoError::Stale {
                    path: path.to_path_buf(),
                    partial,
                });
            }
            std::fs::remove_file(&partial).map_err(|e| IoError::Create {
                path: path.to_path_buf(),
                reason: format!("cannot remove '{}': {e}", partial.display()),
            })?;
        }
        // Laid out under a name of its own and renamed once flushed, so that `.NAME.partial`
        // is never a file HDF5 cannot open: a run killed while creating it left 96 bytes
        // there that neither `inspect`, `--resume` nor h5py could read. What such a kill
        // leaves under the other name is removed here, under the lock, by the next run.
        let new = hidden_sibling(path, "new");
        let _ = std::fs::remove_file(&new);
        let created = without_locking()
            .create_excl(&new)
            .map_err(|e| IoError::Create {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })
            .and_then(|file| Self::layout(path, &partial, file, header))
            .and_then(|writer| {
                std::fs::rename(&new, &partial)
                    .map(|()| writer)
                    .map_err(|e| IoError::Create {
                        path: path.to_path_buf(),
                        reason: format!("cannot rename '{}': {e}", new.display()),
                    })
            });
        match created {
            Ok(mut writer) => {
                writer.overwrite = overwrite;
                writer.lock = Some(lock);
                Ok(writer)
            }
            Err(e) => {
                let _ = std::fs::remove_file(&new);
                Err(e)
            }
        }
    }

    /// Makes the write of `dataset` at frame `frame` fail as a full disk would (tests only).
    #[doc(hidden)]
    pub fn fail_at(&mut self, point: FailPoint) {
        self.fail = Some(point);
    }

    fn injected(&self, frame: usize, dataset: &str) -> hdf5::Result<()> {
        match &self.fail {
            Some(f) if f.frame == frame && f.dataset == dataset => Err(hdf5::Error::from(format!(
                "injected failure writing '{dataset}': No space left on device"
            ))),
            _ => Ok(()),
        }
    }

    /// The temporary name the file is written under until [`finish`](Self::finish).
    pub fn partial(&self) -> &Path {
        &self.partial
    }

    fn layout(
        path: &Path,
        partial: &Path,
        file: File,
        header: &RunHeader,
    ) -> Result<Self, IoError> {
        let n = header.radii.len();
        let at = |what: &str| {
            let what = what.to_string();
            move || what
        };
        // A group for everyone at the start, or none given (−1: not known).
        let groups = match header.groups.len() {
            0 => vec![-1; n],
            g if g == n => header.groups.clone(),
            g => {
                return Err(IoError::Layout {
                    path: path.to_path_buf(),
                    what: format!("{g} groups for {n} radii (one each, or none)"),
                });
            }
        };
        let root: &hdf5::Location = &file;
        for (name, value) in [
            ("wkt_geometry", header.wkt_geometry.as_str()),
            ("format", FORMAT),
            ("moreau_version", header.version.as_str()),
            ("scene", header.scene.as_str()),
            ("scene_name", header.scene_name.as_str()),
            ("solver", header.solver.as_str()),
            ("command", header.command.as_str()),
            ("status", "running"),
            ("summary", "{}"),
        ] {
            set_text(root, name, value).at(path, || format!("writing attribute '{name}'"))?;
        }
        file.new_attr::<u64>()
            .shape(())
            .create("seed")
            .and_then(|a| a.write_scalar(&header.seed))
            .at(path, at("writing attribute 'seed'"))?;
        file.create_group("frames")
            .and_then(|_| file.create_group("people"))
            .at(path, at("creating groups"))?;

        // Appended tables are not compressed: every frame rewrites their last chunk, and a
        // compressed chunk that grows moves to new space while the index on disk (from the last
        // flush) still points to the old one, whose space HDF5 may hand to the next write. A
        // SIGKILL in between left a chunk that no longer inflates ("filter returned failure
        // during read" on /steps, seen in CI). An uncompressed chunk keeps its address, so a
        // killed run's file reads back whole up to its last flush. (frames/positions and
        // frames/pressure write each chunk once and stay compressed.)
        // Small tables get small chunks: an uncompressed chunk takes its whole size on disk.
        fn table<T: H5Type>(file: &File, name: &str, rows: usize) -> hdf5::Result<Dataset> {
            file.new_dataset::<T>().chunk(rows).shape(0..).create(name)
        }
        let trajectory = table::<TrajectoryRow>(&file, TRAJECTORY, ROWS_PER_CHUNK)
            .at(path, at("creating 'trajectory'"))?;
        trajectory
            .new_attr::<f64>()
            .shape(())
            .create("fps")
            .and_then(|a| a.write_scalar(&header.fps))
            .at(path, at("writing attribute 'trajectory.fps'"))?;
        let exits = table::<ExitRow>(&file, EXITS, SMALL_ROWS_PER_CHUNK)
            .at(path, at("creating 'exits'"))?;
        if !header.exit_names.is_empty() {
            let names: Vec<VarLenUnicode> = header.exit_names.iter().map(|n| text(n)).collect();
            exits
                .new_attr_builder()
                .with_data(&names)
                .create("names")
                .at(path, at("writing attribute 'exits.names'"))?;
        }
        let steps = table::<StepRow>(&file, STEPS, SMALL_ROWS_PER_CHUNK)
            .at(path, at("creating 'steps'"))?;
        let frame_time = table::<f64>(&file, FRAME_TIME, SMALL_ROWS_PER_CHUNK)
            .at(path, at("creating 'frames/time'"))?;
        let frame_count = table::<i64>(&file, FRAME_COUNT, SMALL_ROWS_PER_CHUNK)
            .at(path, at("creating 'frames/count'"))?;
        let positions = file
            .new_dataset::<f64>()
            .chunk((1, n.clamp(MIN_PEOPLE_PER_CHUNK, PEOPLE_PER_CHUNK), 2))
            .shuffle()
            .deflate(DEFLATE)
            .fill_value(f64::NAN)
            .shape((0.., n.., 2))
            .create(FRAME_POSITIONS)
            .at(path, at("creating 'frames/positions'"))?;
        let walls: Vec<f64> = header.walls.iter().flatten().copied().collect();
        file.new_dataset_builder()
            .with_data(
                &ndarray::Array2::from_shape_vec((header.walls.len(), 4), walls)
                    .expect("4 numbers a wall"),
            )
            .create(WALLS)
            .at(path, at("writing 'walls'"))?;
        let contacts = if header.contacts {
            let rows = table::<ContactRow>(&file, CONTACTS, ROWS_PER_CHUNK)
                .at(path, at("creating 'contacts'"))?;
            rows.new_attr::<VarLenUnicode>()
                .shape(())
                .create("units")
                .and_then(|a| {
                    a.write_scalar(&text(
                        "lambda: m/s, the speed a contact removed along its normal (v = w + Σ λ ∇g)",
                    ))
                })
                .at(path, at("writing attribute 'contacts.units'"))?;
            let pressure = file
                .new_dataset::<f64>()
                .chunk((1, n.clamp(2 * MIN_PEOPLE_PER_CHUNK, 2 * PEOPLE_PER_CHUNK)))
                .shuffle()
                .deflate(DEFLATE)
                .fill_value(f64::NAN)
                .shape((0.., n..))
                .create(FRAME_PRESSURE)
                .at(path, at("creating 'frames/pressure'"))?;
            Some((rows, pressure))
        } else {
            None
        };
        // The people at the start; those who enter later are appended with the frame after.
        let segments = header.moving_body.len();
        let moving = if segments > 0 {
            file.create_group("moving")
                .at(path, at("creating group 'moving'"))?;
            let names: Vec<VarLenUnicode> = header.moving_names.iter().map(|n| text(n)).collect();
            file.new_dataset_builder()
                .with_data(&names)
                .create(MOVING_NAME)
                .at(path, at("writing 'moving/name'"))?;
            let body: Vec<i64> = header.moving_body.iter().map(|&b| b.into()).collect();
            file.new_dataset_builder()
                .with_data(&body)
                .create(MOVING_BODY)
                .at(path, at("writing 'moving/body'"))?;
            Some(
                file.new_dataset::<f64>()
                    .chunk((1, segments, 4))
                    .shape((0.., segments, 4))
                    .create(FRAME_MOVING_WALLS)
                    .at(path, at("creating 'frames/moving_walls'"))?,
            )
        } else {
            None
        };
        let ids: Vec<i64> = (0..n as i64).collect();
        let people_id = table::<i64>(&file, PEOPLE_ID, ROWS_PER_CHUNK)
            .and_then(|ds| append(&ds, &mut 0, &ids).map(|()| ds))
            .at(path, at("writing 'people/id'"))?;
        let people_radius = table::<f64>(&file, PEOPLE_RADIUS, ROWS_PER_CHUNK)
            .and_then(|ds| append(&ds, &mut 0, &header.radii).map(|()| ds))
            .at(path, at("writing 'people/radius'"))?;
        let people_entry = table::<f64>(&file, PEOPLE_ENTRY_TIME, ROWS_PER_CHUNK)
            .and_then(|ds| append(&ds, &mut 0, &vec![0.0; n]).map(|()| ds))
            .at(path, at("writing 'people/entry_time'"))?;
        let people_group = file
            .new_dataset::<i64>()
            .chunk(ROWS_PER_CHUNK)
            .shape(0..)
            .fill_value(-1i64)
            .create(PEOPLE_GROUP)
            .and_then(|ds| append(&ds, &mut 0, &groups).map(|()| ds))
            .at(path, at("writing 'people/group'"))?;
        let state = StateSlots::create(&file).at(path, at("creating 'state'"))?;
        file.flush().at(path, at("flushing"))?;
        Ok(Self {
            path: path.to_path_buf(),
            partial: partial.to_path_buf(),
            overwrite: Overwrite::Never,
            lock: None,
            fail: None,
            file,
            people_id,
            people_radius,
            people_entry,
            people_group,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            moving,
            moving_segments: segments,
            state,
            people: n,
            pending_people: Vec::new(),
            frames: 0,
            fps: header.fps,
            trajectory_rows: 0,
            exit_rows: 0,
            step_rows: 0,
            contact_rows: 0,
            exit_times: vec![f64::NAN; n],
            pending_steps: Vec::new(),
            pending_exits: Vec::new(),
            rows: Vec::new(),
            dense: Vec::new(),
            pending_contacts: Vec::new(),
            pending_pressure: Vec::new(),
            pending_moving: Vec::new(),
        })
    }

    /// The output path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames written so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Records a step (written with the next frame).
    pub fn step(&mut self, report: &StepReport) {
        self.pending_steps.push(StepRow::from(report));
    }

    /// Records a step already in its stored form (written with the next frame).
    pub(crate) fn step_row(&mut self, row: StepRow) {
        self.pending_steps.push(row);
    }

    /// People the file holds: at the start, and every one who entered since (ids `0..people`).
    pub fn people(&self) -> usize {
        self.people + self.pending_people.len()
    }

    /// Records that person `id` of radius `radius` and group `group` entered the run at time
    /// `t` (written with the next frame, or when the run ends): ids come in order, each the
    /// next one.
    pub fn enter(&mut self, id: u32, radius: f64, t: f64, group: u32) -> Result<(), IoError> {
        let next = self.people();
        if id as usize != next {
            return Err(self.layout_error(format!(
                "person {id} entered, but the next id is {next} (people enter in order of id)"
            )));
        }
        self.pending_people.push(Newcomer {
            radius,
            t,
            group: i64::from(group),
        });
        self.exit_times.push(f64::NAN);
        Ok(())
    }

    /// Records that person `id` passed exit `exit` (its index in the scene) at time `t`
    /// (written with the next frame).
    pub fn exit(&mut self, id: u32, exit: u32, t: f64) -> Result<(), IoError> {
        let people = self.people();
        let slot = self
            .exit_times
            .get_mut(id as usize)
            .ok_or_else(|| IoError::Layout {
                path: self.path.clone(),
                what: format!("exit of person {id}, but the file holds {people} people"),
            })?;
        *slot = t;
        self.pending_exits.push(ExitRow {
            id: id as i64,
            exit: exit.into(),
            t,
        });
        Ok(())
    }

    /// Whether the file records contact forces.
    pub fn records_contacts(&self) -> bool {
        self.contacts.is_some()
    }

    /// Records the contact forces of the next frame (written with it): the contacts with
    /// `λ > 10⁻⁶ m/s` (their `frame` is set here) and the pressure by person id (`people` values,
    /// NaN when absent). Ignored when the file does not record contacts.
    pub fn contacts(
        &mut self,
        rows: impl IntoIterator<Item = ContactRow>,
        pressure_by_id: &[f64],
    ) -> Result<(), IoError> {
        if self.contacts.is_none() {
            return Ok(());
        }
        if pressure_by_id.len() != self.people() {
            return Err(self.layout_error(format!(
                "pressure of {} people, but the file holds {}",
                pressure_by_id.len(),
                self.people()
            )));
        }
        let frame = self.frames as i64;
        self.pending_contacts.clear();
        self.pending_contacts
            .extend(rows.into_iter().map(|r| ContactRow { frame, ..r }));
        self.pending_pressure.clear();
        self.pending_pressure.extend_from_slice(pressure_by_id);
        Ok(())
    }

    /// Records the segments of the moving bodies at the next frame (written with it), one
    /// `[x0, y0, x1, y1]` each in `moving/body` order. Required before every frame of a file
    /// with moving bodies; an error for a file without.
    pub fn moving_walls(&mut self, segments: &[[f64; 4]]) -> Result<(), IoError> {
        if segments.len() != self.moving_segments {
            return Err(self.layout_error(format!(
                "{} moving segments, but the file holds {}",
                segments.len(),
                self.moving_segments
            )));
        }
        self.pending_moving.clear();
        self.pending_moving.extend(segments.iter().flatten());
        Ok(())
    }

    /// Saves the run's state after the last frame (the bytes of a `SimState`) into the slot
    /// not in use, then says so and flushes: a run killed at any moment leaves one whole state
    /// and the counts of rows it goes with, for [`resume`](Self::resume). Between frames only
    /// (nothing pending).
    pub fn save_state(&mut self, bytes: &[u8]) -> Result<(), IoError> {
        self.save_state_noted(bytes, "")
    }

    /// [`save_state`](Self::save_state), with a text kept beside the bytes and given back by
    /// [`RunWriter::resume`] (the run's totals so far, which a resumed run goes on from).
    pub fn save_state_noted(&mut self, bytes: &[u8], note: &str) -> Result<(), IoError> {
        if !self.pending_steps.is_empty()
            || !self.pending_exits.is_empty()
            || !self.pending_people.is_empty()
        {
            return Err(self.layout_error(format!(
                "a state saved between frames ({} steps, {} exits, {} people not yet written)",
                self.pending_steps.len(),
                self.pending_exits.len(),
                self.pending_people.len()
            )));
        }
        let marks = StateMarks {
            people: self.people,
            frames: self.frames,
            steps: self.step_rows,
            exits: self.exit_rows,
            trajectory_rows: self.trajectory_rows,
            contact_rows: self.contact_rows,
        };
        let path = self.path.clone();
        self.state
            .save(bytes, marks, note)
            .and_then(|()| self.file.flush())
            .at(&path, || {
                format!("saving the state after frame {}", marks.frames)
            })
    }

    /// Reopens the partial file a killed run left for `path` ([`partial_path`]) to go on from
    /// its last saved state: every dataset is cut back to where that state was saved (rows
    /// written after it are dropped; the run will write them again), and the writer, the
    /// header and the state's bytes are returned. `overwrite` is the rule for moving the file
    /// to `path` when the run ends.
    pub fn resume(path: &Path, overwrite: Overwrite) -> Result<Resumed, IoError> {
        let lock = OutputLock::acquire(path)?;
        let partial = partial_path(path);
        // A run stopped by SIGINT or SIGTERM (a batch system's time limit) finished its file
        // as `interrupted`, with its saved state: it goes on as a killed one does (it could
        // not be resumed, while a SIGKILL could). Under the lock, back to its partial name.
        if !partial.is_file() && interrupted(path) {
            std::fs::rename(path, &partial).map_err(|e| IoError::Create {
                path: path.to_path_buf(),
                reason: format!("cannot move it back to '{}': {e}", partial.display()),
            })?;
        }
        if !partial.is_file() {
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: format!(
                    "nothing to resume: no partial file '{}' (a run killed while writing \
                     '{}' leaves one)",
                    partial.display(),
                    path.display()
                ),
            });
        }
        let mut header = crate::RunFile::open(&partial)?.header()?;
        let file = without_locking()
            .open_rw(&partial)
            .at(&partial, || "opening for writing".into())?;
        end_of_allocation_at_end_of_file(&file);
        let format = file
            .attr("format")
            .and_then(|a| a.read_scalar::<VarLenUnicode>())
            .at(&partial, || "reading attribute 'format'".into())?;
        set_text(&file, "status", "running")
            .at(&partial, || "writing attribute 'status'".into())?;
        if format.as_str() != FORMAT {
            return Err(IoError::Layout {
                path: partial,
                what: format!(
                    "format '{format}': this moreau resumes only its own format '{FORMAT}' \
                     (`moreau run --from` runs the file's scene again)"
                ),
            });
        }
        let at = |what: &str| {
            let what = what.to_string();
            move || what
        };
        // A run killed inside `finish` may have written `people/exit_time`, which `finish`
        // creates: the resumed run's `finish` failed on it ("unknown library error").
        if file.link_exists(PEOPLE_EXIT_TIME) {
            file.unlink(PEOPLE_EXIT_TIME)
                .at(&partial, at("removing the unfinished 'people/exit_time'"))?;
        }
        let state = StateSlots::open(&file).at(&partial, at("opening 'state'"))?;
        let (bytes, marks, note) = state.load().at(&partial, at("reading the saved state"))?;
        let Some(marks) = marks else {
            return Err(IoError::Layout {
                path: partial,
                what: "nothing to resume: the run was killed before it saved a state (after its \
                       first frame, or a later one for a large crowd); run it again with --force"
                    .into(),
            });
        };
        let open = |name: &str| {
            file.dataset(name)
                .at(&partial, || format!("opening '{name}'"))
        };
        let (people_id, people_radius) = (open(PEOPLE_ID)?, open(PEOPLE_RADIUS)?);
        // Entry times, in files written since 2026-11-28; an older file's people get NaN
        // (unknown), those who enter from here on their time.
        let people_entry = match file.dataset(PEOPLE_ENTRY_TIME) {
            Ok(ds) => ds,
            Err(_) => file
                .new_dataset::<f64>()
                .chunk(ROWS_PER_CHUNK)
                .shape(0..)
                .create(PEOPLE_ENTRY_TIME)
                .and_then(|ds| append(&ds, &mut 0, &vec![f64::NAN; people_id.size()]).map(|()| ds))
                .at(&partial, || "creating 'people/entry_time'".into())?,
        };
        // Groups, in files written since /people/group was added (2026-11-28, evening); an
        // older file's people get −1 (unknown).
        let people_group = match file.dataset(PEOPLE_GROUP) {
            Ok(ds) => ds,
            Err(_) => file
                .new_dataset::<i64>()
                .chunk(ROWS_PER_CHUNK)
                .shape(0..)
                .fill_value(-1i64)
                .create(PEOPLE_GROUP)
                .and_then(|ds| append(&ds, &mut 0, &vec![-1i64; people_id.size()]).map(|()| ds))
                .at(&partial, || "creating 'people/group'".into())?,
        };
        let (trajectory, frame_time, frame_count, positions, exits, steps) = (
            open(TRAJECTORY)?,
            open(FRAME_TIME)?,
            open(FRAME_COUNT)?,
            open(FRAME_POSITIONS)?,
            open(EXITS)?,
            open(STEPS)?,
        );
        let contacts = if header.contacts {
            Some((open(CONTACTS)?, open(FRAME_PRESSURE)?))
        } else {
            None
        };
        let segments = header.moving_body.len();
        let moving = if segments > 0 {
            Some(open(FRAME_MOVING_WALLS)?)
        } else {
            None
        };
        // Each mark counts rows written before the state was saved: a mark beyond its
        // dataset's rows is a damaged file, refused before anything is cut back.
        let mut beyond = vec![
            ("people", marks.people, PEOPLE_ID, people_id.size()),
            ("people", marks.people, PEOPLE_RADIUS, people_radius.size()),
            (
                "people",
                marks.people,
                PEOPLE_ENTRY_TIME,
                people_entry.size(),
            ),
            ("people", marks.people, PEOPLE_GROUP, people_group.size()),
            ("frames", marks.frames, FRAME_TIME, frame_time.size()),
            ("frames", marks.frames, FRAME_COUNT, frame_count.size()),
            (
                "frames",
                marks.frames,
                FRAME_POSITIONS,
                positions.shape().first().copied().unwrap_or(0),
            ),
            ("steps", marks.steps, STEPS, steps.size()),
            ("exits", marks.exits, EXITS, exits.size()),
            (
                "trajectory_rows",
                marks.trajectory_rows,
                TRAJECTORY,
                trajectory.size(),
            ),
        ];
        if let Some((rows, _)) = &contacts {
            beyond.push(("contact_rows", marks.contact_rows, CONTACTS, rows.size()));
        }
        if let Some((mark, value, dataset, rows)) =
            beyond.into_iter().find(|&(_, value, _, rows)| value > rows)
        {
            return Err(IoError::Layout {
                path: partial,
                what: format!(
                    "the saved state's mark '{STATE}/{mark}' = {value} is beyond the {rows} \
                     rows of '{dataset}' (a damaged file: nothing was changed)"
                ),
            });
        }
        // The people of the saved frame (rows of people who entered after it are dropped).
        let n = marks.people;
        if n > header.radii.len() {
            return Err(IoError::Layout {
                path: partial,
                what: format!(
                    "the saved state marks {n} people, 'people/radius' holds {}",
                    header.radii.len()
                ),
            });
        }
        header.radii.truncate(n);
        header.groups.truncate(n);
        let exit_rows: Vec<ExitRow> = exits
            .read_slice_1d(0..marks.exits)
            .map(|a| a.to_vec())
            .at(&partial, at("reading 'exits'"))?;
        let mut exit_times = vec![f64::NAN; n];
        for row in &exit_rows {
            if let Some(t) = exit_times.get_mut(row.id as usize) {
                *t = row.t;
            }
        }
        let writer = Self {
            path: path.to_path_buf(),
            partial: partial.clone(),
            overwrite,
            lock: Some(lock),
            fail: None,
            file,
            people_id,
            people_radius,
            people_entry,
            people_group,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            moving,
            moving_segments: segments,
            state,
            people: n,
            pending_people: Vec::new(),
            frames: marks.frames,
            fps: header.fps,
            trajectory_rows: marks.trajectory_rows,
            exit_rows: marks.exits,
            step_rows: marks.steps,
            contact_rows: marks.contact_rows,
            exit_times,
            pending_steps: Vec::new(),
            pending_exits: Vec::new(),
            rows: Vec::new(),
            dense: Vec::new(),
            pending_contacts: Vec::new(),
            pending_pressure: Vec::new(),
            pending_moving: Vec::new(),
        };
        writer
            .roll_back()
            .and_then(|()| writer.file.flush())
            .at(&partial, at("cutting the datasets back to the saved state"))?;
        Ok(Resumed {
            writer,
            header,
            state: bytes,
            note,
        })
    }

    /// Writes one output frame, `positions = [x0, y0, x1, y1, ...]` of the people `ids`, with
    /// the steps and exits recorded since the last one, and flushes the file.
    pub fn frame(&mut self, t: f64, ids: &[u32], positions: &[f64]) -> Result<(), IoError> {
        if positions.len() != 2 * ids.len() {
            return Err(self.layout_error(format!(
                "frame at t = {}: {} coordinates for {} people",
                Num(t),
                positions.len(),
                ids.len()
            )));
        }
        let frame = self.frames;
        let people = self.people();
        let pedpy_frame = trajectory_frame(t, self.fps);
        self.rows.clear();
        self.dense.clear();
        self.dense.resize(2 * people, f64::NAN);
        for (k, &id) in ids.iter().enumerate() {
            let i = id as usize;
            if i >= people {
                return Err(self.layout_error(format!(
                    "frame at t = {}: person {id}, but the file holds {people} people",
                    Num(t)
                )));
            }
            let (x, y) = (positions[2 * k], positions[2 * k + 1]);
            if let Some(frame) = pedpy_frame {
                self.rows.push(TrajectoryRow {
                    id: i as i64,
                    frame,
                    x,
                    y,
                });
            }
            self.dense[2 * i] = x;
            self.dense[2 * i + 1] = y;
        }
        if self.pending_pressure.len() != people {
            self.pending_pressure.clear();
            self.pending_pressure.resize(people, f64::NAN);
        }
        if self.pending_moving.len() != 4 * self.moving_segments {
            return Err(self.layout_error(format!(
                "frame at t = {}: the moving walls were not given (the file holds {} moving \
                 segments)",
                Num(t),
                self.moving_segments
            )));
        }
        // Every dataset of the frame is extended and written before any count moves; if one
        // fails, every extent goes back to the last whole frame, so no reader sees a row of a
        // frame that was not written whole (HDF5 fills a chunk it could not write with zeros).
        let written = self.write_frame(frame, t, ids.len());
        if let Err((dataset, source)) = written {
            let rolled_back = self.roll_back();
            let _ = self.file.flush();
            return Err(IoError::Hdf5 {
                path: self.path.clone(),
                what: format!(
                    "frame {frame} (t = {t}): writing '{dataset}' (the file keeps its {frame} \
                     whole frames{})",
                    match rolled_back {
                        Ok(()) => String::new(),
                        Err(e) => format!("; taking the frame back failed too: {e}"),
                    }
                ),
                source,
            });
        }
        self.pending_contacts.clear();
        self.pending_pressure.clear();
        self.pending_moving.clear();
        self.pending_steps.clear();
        self.pending_exits.clear();
        self.pending_people.clear();
        self.people = people;
        self.frames += 1;
        Ok(())
    }

    /// Writes frame `frame`, committing the row counts only when every dataset and the flush
    /// succeeded; on failure, names the dataset.
    fn write_frame(
        &mut self,
        frame: usize,
        t: f64,
        count: usize,
    ) -> Result<(), (&'static str, hdf5::Error)> {
        fn named<T>(
            name: &'static str,
            r: hdf5::Result<T>,
        ) -> Result<T, (&'static str, hdf5::Error)> {
            r.map_err(|e| (name, e))
        }
        let people = self.people();
        named(PEOPLE_ID, self.injected(frame, PEOPLE_ID))?;
        named(PEOPLE_ID, self.append_people_ids())?;
        named(PEOPLE_RADIUS, self.injected(frame, PEOPLE_RADIUS))?;
        named(PEOPLE_RADIUS, self.append_newcomers())?;
        let mut trajectory_rows = self.trajectory_rows;
        named(TRAJECTORY, self.injected(frame, TRAJECTORY))?;
        named(
            TRAJECTORY,
            append(&self.trajectory, &mut trajectory_rows, &self.rows),
        )?;
        named(FRAME_POSITIONS, self.injected(frame, FRAME_POSITIONS))?;
        named(
            FRAME_POSITIONS,
            self.positions.resize((frame + 1, people, 2)).and_then(|_| {
                let view = ArrayView2::from_shape((people, 2), &self.dense)
                    .expect("2 coordinates a person");
                self.positions.write_slice(view, (frame, .., ..))
            }),
        )?;
        named(FRAME_TIME, self.injected(frame, FRAME_TIME))?;
        named(FRAME_TIME, append(&self.frame_time, &mut { frame }, &[t]))?;
        named(FRAME_COUNT, self.injected(frame, FRAME_COUNT))?;
        named(
            FRAME_COUNT,
            append(&self.frame_count, &mut { frame }, &[count as i64]),
        )?;
        let mut contact_rows = self.contact_rows;
        if let Some((rows, pressure)) = &self.contacts {
            named(CONTACTS, self.injected(frame, CONTACTS))?;
            named(
                CONTACTS,
                append(rows, &mut contact_rows, &self.pending_contacts),
            )?;
            named(FRAME_PRESSURE, self.injected(frame, FRAME_PRESSURE))?;
            named(
                FRAME_PRESSURE,
                pressure.resize((frame + 1, people)).and_then(|_| {
                    pressure.write_slice(self.pending_pressure.as_slice(), (frame, ..))
                }),
            )?;
        }
        if let Some(moving) = &self.moving {
            named(FRAME_MOVING_WALLS, self.injected(frame, FRAME_MOVING_WALLS))?;
            named(
                FRAME_MOVING_WALLS,
                moving
                    .resize((frame + 1, self.moving_segments, 4))
                    .and_then(|_| {
                        let view =
                            ArrayView2::from_shape((self.moving_segments, 4), &self.pending_moving)
                                .expect("4 numbers a segment");
                        moving.write_slice(view, (frame, .., ..))
                    }),
            )?;
        }
        let mut step_rows = self.step_rows;
        named(STEPS, self.injected(frame, STEPS))?;
        named(
            STEPS,
            append(&self.steps, &mut step_rows, &self.pending_steps),
        )?;
        let mut exit_rows = self.exit_rows;
        named(EXITS, self.injected(frame, EXITS))?;
        named(
            EXITS,
            append(&self.exits, &mut exit_rows, &self.pending_exits),
        )?;
        named("flush", self.injected(frame, "flush"))?;
        named("flush", self.file.flush())?;
        self.trajectory_rows = trajectory_rows;
        self.contact_rows = contact_rows;
        self.step_rows = step_rows;
        self.exit_rows = exit_rows;
        Ok(())
    }

    /// Sets every dataset's extent back to the rows of the whole frames written.
    fn roll_back(&self) -> hdf5::Result<()> {
        let frames = self.frames;
        let mut first: hdf5::Result<()> = Ok(());
        let mut keep = |r: hdf5::Result<()>| {
            if first.is_ok() {
                first = r;
            }
        };
        keep(self.people_id.resize(self.people));
        keep(self.people_radius.resize(self.people));
        keep(self.people_entry.resize(self.people));
        keep(self.people_group.resize(self.people));
        keep(self.trajectory.resize(self.trajectory_rows));
        keep(self.positions.resize((frames, self.people, 2)));
        keep(self.frame_time.resize(frames));
        keep(self.frame_count.resize(frames));
        if let Some((rows, pressure)) = &self.contacts {
            keep(rows.resize(self.contact_rows));
            keep(pressure.resize((frames, self.people)));
        }
        if let Some(moving) = &self.moving {
            keep(moving.resize((frames, self.moving_segments, 4)));
        }
        keep(self.steps.resize(self.step_rows));
        keep(self.exits.resize(self.exit_rows));
        first
    }

    /// Appends the radii, entry times and groups of the people who entered since the last
    /// frame to `people/radius`, `people/entry_time` and `people/group`.
    fn append_newcomers(&self) -> hdf5::Result<()> {
        let column =
            |f: fn(&Newcomer) -> f64| -> Vec<f64> { self.pending_people.iter().map(f).collect() };
        let groups: Vec<i64> = self.pending_people.iter().map(|p| p.group).collect();
        append(
            &self.people_radius,
            &mut { self.people },
            &column(|p| p.radius),
        )?;
        append(&self.people_entry, &mut { self.people }, &column(|p| p.t))?;
        append(&self.people_group, &mut { self.people }, &groups)
    }

    /// Appends the ids of the people who entered since the last frame to `people/id`.
    fn append_people_ids(&self) -> hdf5::Result<()> {
        let ids: Vec<i64> = (self.people as i64..self.people() as i64).collect();
        append(&self.people_id, &mut { self.people }, &ids)
    }

    /// Writes the pending steps, exits and people (at the end of a run), all or none: the
    /// people who entered after the last frame get their `people` rows and a NaN column in the
    /// per-frame arrays.
    fn flush_rows(&mut self) -> hdf5::Result<()> {
        let (mut steps, mut exits) = (self.step_rows, self.exit_rows);
        let people = self.people();
        let written = append(&self.steps, &mut steps, &self.pending_steps)
            .and_then(|_| append(&self.exits, &mut exits, &self.pending_exits))
            .and_then(|_| self.append_people_ids())
            .and_then(|_| self.append_newcomers())
            .and_then(|_| self.positions.resize((self.frames, people, 2)))
            .and_then(|_| match &self.contacts {
                Some((_, pressure)) => pressure.resize((self.frames, people)),
                None => Ok(()),
            });
        match written {
            Ok(()) => {
                (self.step_rows, self.exit_rows) = (steps, exits);
                self.pending_steps.clear();
                self.pending_exits.clear();
                self.pending_people.clear();
                self.people = people;
                Ok(())
            }
            Err(e) => {
                let _ = self.roll_back();
                Err(e)
            }
        }
    }

    fn layout_error(&self, what: String) -> IoError {
        IoError::Layout {
            path: self.path.clone(),
            what,
        }
    }

    /// Ends the run: writes what is pending, `people/exit_time`, `status` (`complete`,
    /// `interrupted` or `failed: …`) and `summary` (JSON), closes the file and moves it from
    /// its temporary name to its name (over an old file only with [`Overwrite::Allowed`]).
    /// Each part is tried even when one before it failed (a full disk may still take the
    /// status); the first error is returned. The file is moved to its name in every case but
    /// one: when `path` appeared meanwhile and may not be replaced, it stays at its temporary
    /// name, which the error gives.
    pub fn finish(mut self, status: &str, summary: &str) -> Result<(), IoError> {
        let path = self.path.clone();
        let mut first: Option<IoError> = None;
        let mut keep = |r: Result<(), IoError>| {
            if let Err(e) = r {
                first.get_or_insert(e);
            }
        };
        keep(
            self.flush_rows()
                .at(&path, || "writing 'steps', 'exits' and 'people'".into()),
        );
        keep(
            self.file
                .new_dataset_builder()
                .with_data(&self.exit_times)
                .create(PEOPLE_EXIT_TIME)
                .map(|_| ())
                .at(&path, || "writing 'people/exit_time'".into()),
        );
        keep(
            set_text(&self.file, "status", status)
                .at(&path, || "writing attribute 'status'".into()),
        );
        keep(
            set_text(&self.file, "summary", summary)
                .at(&path, || "writing attribute 'summary'".into()),
        );
        keep(self.file.flush().at(&path, || "flushing".into()));
        let RunWriter {
            partial,
            overwrite,
            lock,
            file,
            people_id,
            people_radius,
            people_entry,
            people_group,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            state,
            ..
        } = self;
        drop((
            people_id,
            people_radius,
            people_entry,
            people_group,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            state,
        ));
        keep(file.close().at(&path, || "closing".into()));
        keep(publish(&partial, &path, overwrite).map_err(|e| match e {
            IoError::Exists { .. } => IoError::Create {
                path: path.clone(),
                reason: format!(
                    "it appeared while the run went on and --force was not given; the run is \
                     in '{}'",
                    partial.display()
                ),
            },
            other => other,
        }));
        drop(lock);
        first.map_or(Ok(()), Err)
    }
}

/// Moves the laid-out file `from` to `to`: never over an existing file unless allowed.
fn publish(from: &Path, to: &Path, overwrite: Overwrite) -> Result<(), IoError> {
    let failed = |e: std::io::Error| IoError::Create {
        path: to.to_path_buf(),
        reason: e.to_string(),
    };
    match overwrite {
        Overwrite::Allowed => std::fs::rename(from, to).map_err(failed),
        // A hard link fails if `to` exists, atomically; then drop the temporary name.
        Overwrite::Never => match std::fs::hard_link(from, to) {
            Ok(()) => std::fs::remove_file(from).map_err(failed),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Err(IoError::Exists {
                path: to.to_path_buf(),
            }),
            // File systems without hard links: check, then rename.
            Err(_) if !to.exists() => std::fs::rename(from, to).map_err(failed),
            Err(_) => Err(IoError::Exists {
                path: to.to_path_buf(),
            }),
        },
    }
}

/// Appends `rows` to the 1-D dataset `ds` that holds `len` rows.
fn append<T: H5Type>(ds: &Dataset, len: &mut usize, rows: &[T]) -> hdf5::Result<()> {
    if rows.is_empty() {
        return Ok(());
    }
    let end = *len + rows.len();
    ds.resize(end)?;
    ds.write_slice(rows, *len..end)?;
    *len = end;
    Ok(())
}
