//! Writing a run file as the run goes: buffered between output frames, flushed at each.

use std::path::{Path, PathBuf};

use hdf5::types::VarLenUnicode;
use hdf5::{Dataset, File, H5Type};
use moreau_core::StepReport;
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

/// Writes one run file. Rows given between two frames are held in memory and written with
/// the next frame, then the file is flushed: on disk the file is always a whole number of
/// frames, whatever moment the process dies.
#[derive(Debug)]
pub struct RunWriter {
    path: PathBuf,
    file: File,
    trajectory: Dataset,
    frame_time: Dataset,
    frame_count: Dataset,
    positions: Dataset,
    exits: Dataset,
    steps: Dataset,
    /// `/contacts` and `/frames/pressure`, when the run records contact forces.
    contacts: Option<(Dataset, Dataset)>,
    people: usize,
    frames: usize,
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
    /// Creates the file, its datasets and its attributes, and flushes it (status `running`).
    /// The file is laid out under a temporary name in the same directory and moved to `path`
    /// only when complete, so `path` never holds a half-made file, and with
    /// [`Overwrite::Allowed`] the old file stays whole until the new one replaces it.
    /// Nothing is left behind when this fails.
    pub fn create(path: &Path, header: &RunHeader, overwrite: Overwrite) -> Result<Self, IoError> {
        check_output(path, overwrite)?;
        if !(header.fps > 0.0 && header.fps.is_finite()) {
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: format!("fps must be > 0 and finite, got {}", header.fps),
            });
        }
        let name = path
            .file_name()
            .map_or("run".into(), |n| n.to_string_lossy());
        let partial = path.with_file_name(format!(".{name}.{}.partial", std::process::id()));
        let created = File::create_excl(&partial)
            .map_err(|e| IoError::Create {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })
            .and_then(|file| Self::layout(path, file, header))
            .and_then(|writer| {
                publish(&partial, path, overwrite)?;
                Ok(writer)
            });
        if created.is_err() {
            let _ = std::fs::remove_file(&partial);
        }
        created
    }

    fn layout(path: &Path, file: File, header: &RunHeader) -> Result<Self, IoError> {
        let n = header.radii.len();
        let at = |what: &str| {
            let what = what.to_string();
            move || what
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

        fn table<T: H5Type>(file: &File, name: &str) -> hdf5::Result<Dataset> {
            file.new_dataset::<T>()
                .chunk(ROWS_PER_CHUNK)
                .shuffle()
                .deflate(DEFLATE)
                .shape(0..)
                .create(name)
        }
        let trajectory =
            table::<TrajectoryRow>(&file, TRAJECTORY).at(path, at("creating 'trajectory'"))?;
        trajectory
            .new_attr::<f64>()
            .shape(())
            .create("fps")
            .and_then(|a| a.write_scalar(&header.fps))
            .at(path, at("writing attribute 'trajectory.fps'"))?;
        let exits = table::<ExitRow>(&file, EXITS).at(path, at("creating 'exits'"))?;
        let steps = table::<StepRow>(&file, STEPS).at(path, at("creating 'steps'"))?;
        let frame_time = table::<f64>(&file, FRAME_TIME).at(path, at("creating 'frames/time'"))?;
        let frame_count =
            table::<i64>(&file, FRAME_COUNT).at(path, at("creating 'frames/count'"))?;
        let positions = file
            .new_dataset::<f64>()
            .chunk((1, n.clamp(1, PEOPLE_PER_CHUNK), 2))
            .shuffle()
            .deflate(DEFLATE)
            .fill_value(f64::NAN)
            .shape((0.., n, 2))
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
            let rows = table::<ContactRow>(&file, CONTACTS).at(path, at("creating 'contacts'"))?;
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
                .chunk((1, n.clamp(1, 2 * PEOPLE_PER_CHUNK)))
                .shuffle()
                .deflate(DEFLATE)
                .fill_value(f64::NAN)
                .shape((0.., n))
                .create(FRAME_PRESSURE)
                .at(path, at("creating 'frames/pressure'"))?;
            Some((rows, pressure))
        } else {
            None
        };
        let ids: Vec<i64> = (0..n as i64).collect();
        file.new_dataset_builder()
            .with_data(&ids)
            .create(PEOPLE_ID)
            .at(path, at("writing 'people/id'"))?;
        file.new_dataset_builder()
            .with_data(&header.radii)
            .create(PEOPLE_RADIUS)
            .at(path, at("writing 'people/radius'"))?;
        file.flush().at(path, at("flushing"))?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            people: n,
            frames: 0,
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

    /// Records that person `id` passed an exit at time `t` (written with the next frame).
    pub fn exit(&mut self, id: u32, t: f64) -> Result<(), IoError> {
        let slot = self
            .exit_times
            .get_mut(id as usize)
            .ok_or_else(|| IoError::Layout {
                path: self.path.clone(),
                what: format!(
                    "exit of person {id}, but the file holds {} people",
                    self.people
                ),
            })?;
        *slot = t;
        self.pending_exits.push(ExitRow { id: id as i64, t });
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
        if pressure_by_id.len() != self.people {
            return Err(self.layout_error(format!(
                "pressure of {} people, but the file holds {}",
                pressure_by_id.len(),
                self.people
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

    /// Writes one output frame, `positions = [x0, y0, x1, y1, ...]` of the people `ids`, with
    /// the steps and exits recorded since the last one, and flushes the file.
    pub fn frame(&mut self, t: f64, ids: &[u32], positions: &[f64]) -> Result<(), IoError> {
        if positions.len() != 2 * ids.len() {
            return Err(self.layout_error(format!(
                "frame at t = {t}: {} coordinates for {} people",
                positions.len(),
                ids.len()
            )));
        }
        let frame = self.frames;
        self.rows.clear();
        self.dense.clear();
        self.dense.resize(2 * self.people, f64::NAN);
        for (k, &id) in ids.iter().enumerate() {
            let i = id as usize;
            if i >= self.people {
                return Err(self.layout_error(format!(
                    "frame at t = {t}: person {id}, but the file holds {} people",
                    self.people
                )));
            }
            let (x, y) = (positions[2 * k], positions[2 * k + 1]);
            self.rows.push(TrajectoryRow {
                id: i as i64,
                frame: frame as i64,
                x,
                y,
            });
            self.dense[2 * i] = x;
            self.dense[2 * i + 1] = y;
        }
        let path = self.path.clone();
        let what = |w: &str| {
            let w = format!("frame {frame} (t = {t}): {w}");
            move || w
        };
        append(&self.trajectory, &mut self.trajectory_rows, &self.rows)
            .at(&path, what("appending to 'trajectory'"))?;
        self.positions
            .resize((frame + 1, self.people, 2))
            .and_then(|_| {
                let view = ArrayView2::from_shape((self.people, 2), &self.dense)
                    .expect("2 coordinates a person");
                self.positions.write_slice(view, (frame, .., ..))
            })
            .at(&path, what("writing 'frames/positions'"))?;
        let mut n_frames = frame;
        append(&self.frame_time, &mut n_frames, &[t]).at(&path, what("writing 'frames/time'"))?;
        let mut n_frames = frame;
        append(&self.frame_count, &mut n_frames, &[ids.len() as i64])
            .at(&path, what("writing 'frames/count'"))?;
        if let Some((rows, pressure)) = &self.contacts {
            append(rows, &mut self.contact_rows, &self.pending_contacts)
                .at(&path, what("appending to 'contacts'"))?;
            if self.pending_pressure.len() != self.people {
                self.pending_pressure.clear();
                self.pending_pressure.resize(self.people, f64::NAN);
            }
            pressure
                .resize((frame + 1, self.people))
                .and_then(|_| pressure.write_slice(self.pending_pressure.as_slice(), (frame, ..)))
                .at(&path, what("writing 'frames/pressure'"))?;
            self.pending_contacts.clear();
            self.pending_pressure.clear();
        }
        self.flush_rows()
            .at(&path, what("writing 'steps' and 'exits'"))?;
        self.file.flush().at(&path, what("flushing"))?;
        self.frames += 1;
        Ok(())
    }

    fn flush_rows(&mut self) -> hdf5::Result<()> {
        append(&self.steps, &mut self.step_rows, &self.pending_steps)?;
        self.pending_steps.clear();
        append(&self.exits, &mut self.exit_rows, &self.pending_exits)?;
        self.pending_exits.clear();
        Ok(())
    }

    fn layout_error(&self, what: String) -> IoError {
        IoError::Layout {
            path: self.path.clone(),
            what,
        }
    }

    /// Ends the run: writes what is pending, `people/exit_time`, `status` (`complete`, or
    /// `failed: …`) and `summary` (JSON), and closes the file.
    pub fn finish(mut self, status: &str, summary: &str) -> Result<(), IoError> {
        let path = self.path.clone();
        self.flush_rows()
            .at(&path, || "writing 'steps' and 'exits'".into())?;
        self.file
            .new_dataset_builder()
            .with_data(&self.exit_times)
            .create(PEOPLE_EXIT_TIME)
            .at(&path, || "writing 'people/exit_time'".into())?;
        set_text(&self.file, "status", status).at(&path, || "writing attribute 'status'".into())?;
        set_text(&self.file, "summary", summary)
            .at(&path, || "writing attribute 'summary'".into())?;
        self.file.flush().at(&path, || "flushing".into())?;
        let RunWriter {
            file,
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
            ..
        } = self;
        drop((
            trajectory,
            frame_time,
            frame_count,
            positions,
            exits,
            steps,
            contacts,
        ));
        file.close().at(&path, || "closing".into())
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
