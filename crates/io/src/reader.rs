//! Reading a run file back: its header, frames, steps and a description of what it holds.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use hdf5::types::{TypeDescriptor, VarLenUnicode};
use hdf5::{Dataset, File, H5Type};

use crate::error::{Context, IoError};
use crate::layout::*;

/// An open run file (read only).
#[derive(Debug)]
pub struct RunFile {
    path: PathBuf,
    file: File,
}

impl RunFile {
    /// Opens `path`; fails unless it is a moreau run file.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        if path.is_dir() {
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: "is a directory, not a run file".into(),
            });
        }
        if !path.exists() {
            let partial = crate::partial_path(path);
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: if partial.is_file() {
                    format!(
                        "no such file (yet): a run writing it keeps its frames in '{}' until \
                         it ends, and a killed run leaves them there",
                        partial.display()
                    )
                } else {
                    "no such file".into()
                },
            });
        }
        if !path.is_file() {
            return Err(IoError::Layout {
                path: path.to_path_buf(),
                what: "not a regular file".into(),
            });
        }
        // A partial file may be in the middle of a frame's flush (its superblock already
        // names an end of file its data have not reached): wait for the flush, briefly.
        let live = path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().ends_with(".partial"));
        let mut opened = crate::writer::without_locking().open(path);
        for _ in 0..if live { 40 } else { 0 } {
            if opened.is_ok() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
            opened = crate::writer::without_locking().open(path);
        }
        let file = opened.at(path, || {
            "opening it as HDF5 (is it an HDF5 file, and whole, not truncated?)".into()
        })?;
        let me = Self {
            path: path.to_path_buf(),
            file,
        };
        let format = me.text("format")?;
        if !FORMATS_READ.contains(&format.as_str()) {
            return Err(me.layout(format!(
                "format '{format}', this moreau reads {}",
                FORMATS_READ.join(", ")
            )));
        }
        Ok(me)
    }

    fn layout(&self, what: String) -> IoError {
        IoError::Layout {
            path: self.path.clone(),
            what,
        }
    }

    /// A root text attribute.
    pub fn text(&self, name: &str) -> Result<String, IoError> {
        let attr = self
            .file
            .attr(name)
            .map_err(|_| self.layout(format!("no root attribute '{name}'")))?;
        let value: VarLenUnicode = attr
            .read_scalar()
            .at(&self.path, || format!("reading attribute '{name}'"))?;
        Ok(value.as_str().to_string())
    }

    fn dataset(&self, name: &str) -> Result<Dataset, IoError> {
        self.file
            .dataset(name)
            .map_err(|_| self.layout(format!("no dataset '{name}'")))
    }

    /// The rows of dataset `name` as `T`s. HDF5 fills a member of `T` that the file's rows
    /// lack with zeros and says nothing, so a compound `T` with a member the file does not
    /// have is refused here, naming it (the readers of older layouts read them with their own
    /// row types).
    fn read<T: H5Type>(&self, name: &str) -> Result<Vec<T>, IoError> {
        let dataset = self.dataset(name)?;
        if let TypeDescriptor::Compound(wanted) = T::type_descriptor() {
            let has = self.members(&dataset, name)?;
            let missing: Vec<&str> = wanted
                .fields
                .iter()
                .map(|f| f.name.as_str())
                .filter(|m| !has.iter().any(|h| h == m))
                .collect();
            if !missing.is_empty() {
                return Err(self.layout(format!(
                    "dataset '{name}' has no member {} (its rows have {}): not a file this \
                     moreau wrote, or damaged",
                    missing.join(", "),
                    has.join(", ")
                )));
            }
        }
        dataset
            .read_raw()
            .at(&self.path, || format!("reading '{name}'"))
    }

    /// The member names of the rows of `dataset` (named `name`; none unless they are
    /// compound).
    fn members(&self, dataset: &Dataset, name: &str) -> Result<Vec<String>, IoError> {
        let described = dataset
            .dtype()
            .and_then(|t| t.to_descriptor())
            .at(&self.path, || format!("reading the type of '{name}'"))?;
        Ok(match described {
            TypeDescriptor::Compound(c) => c.fields.into_iter().map(|f| f.name).collect(),
            _ => Vec::new(),
        })
    }

    /// The header the writer was given.
    pub fn header(&self) -> Result<RunHeader, IoError> {
        let seed = self
            .file
            .attr("seed")
            .and_then(|a| a.read_scalar::<u64>())
            .at(&self.path, || "reading attribute 'seed'".into())?;
        let fps = self
            .dataset(TRAJECTORY)?
            .attr("fps")
            .and_then(|a| a.read_scalar::<f64>())
            .at(&self.path, || "reading attribute 'trajectory.fps'".into())?;
        Ok(RunHeader {
            version: self.text("moreau_version")?,
            scene_name: self.text("scene_name")?,
            scene: self.text("scene")?,
            seed,
            solver: self.text("solver")?,
            command: self.text("command")?,
            wkt_geometry: self.text("wkt_geometry")?,
            fps,
            radii: self.read(PEOPLE_RADIUS)?,
            groups: self.groups()?.unwrap_or_default(),
            walls: self.walls()?,
            contacts: self.has_contacts(),
            moving_names: if self.file.dataset(MOVING_NAME).is_ok() {
                self.read::<VarLenUnicode>(MOVING_NAME)?
                    .iter()
                    .map(|s| s.as_str().to_string())
                    .collect()
            } else {
                Vec::new()
            },
            exit_names: if let Ok(names) = self.dataset(EXITS)?.attr("names") {
                names
                    .read_raw::<VarLenUnicode>()
                    .at(&self.path, || "reading attribute 'exits.names'".into())?
                    .iter()
                    .map(|s| s.as_str().to_string())
                    .collect()
            } else {
                Vec::new()
            },
            moving_body: if self.file.dataset(MOVING_BODY).is_ok() {
                self.read::<i64>(MOVING_BODY)?
                    .iter()
                    .map(|&b| b as u32)
                    .collect()
            } else {
                Vec::new()
            },
        })
    }

    /// `running` (the writer has not finished: still going, or killed), `complete`, or
    /// `failed: …`.
    pub fn status(&self) -> Result<String, IoError> {
        self.text("status")
    }

    /// The run's summary (JSON; `{}` until the run ends).
    pub fn summary(&self) -> Result<String, IoError> {
        self.text("summary")
    }

    /// The time of every output frame.
    pub fn frame_times(&self) -> Result<Vec<f64>, IoError> {
        self.read(FRAME_TIME)
    }

    /// The number of people present in every output frame.
    pub fn frame_counts(&self) -> Result<Vec<i64>, IoError> {
        self.read(FRAME_COUNT)
    }

    /// Positions `[x0, y0, x1, y1, ...]` by person id at output frame `frame` (NaN: absent).
    pub fn positions(&self, frame: usize) -> Result<Vec<f64>, IoError> {
        let ds = self.dataset(FRAME_POSITIONS)?;
        let frames = ds.shape().first().copied().unwrap_or(0);
        if frame >= frames {
            return Err(self.layout(format!("frame {frame} of {frames}")));
        }
        let a = ds
            .read_slice::<f64, _, ndarray::Ix2>((frame, .., ..))
            .at(&self.path, || format!("reading frame {frame}"))?;
        Ok(a.iter().copied().collect())
    }

    /// The `/trajectory` rows.
    pub fn trajectory(&self) -> Result<Vec<TrajectoryRow>, IoError> {
        self.read(TRAJECTORY)
    }

    /// The `/steps` rows (`time_solve_analyse` and `time_solve_factorize` NaN in files written
    /// before 2026-11-21, which did not measure them).
    pub fn steps(&self) -> Result<Vec<StepRow>, IoError> {
        let has = self.members(&self.dataset(STEPS)?, STEPS)?;
        if has.iter().any(|m| m == "time_solve_analyse") {
            return self.read(STEPS);
        }
        Ok(self
            .read::<StepRowUntimedSolve>(STEPS)?
            .into_iter()
            .map(StepRow::from)
            .collect())
    }

    /// Each person's group, by id: the scene's `[[groups]]` by index, then one per
    /// `[[sources]]` (−1 for those of a file written before it was added, the evening of
    /// 2026-11-28, that a run resumed); `None` for a file written before, which did not store
    /// them.
    pub fn groups(&self) -> Result<Option<Vec<i64>>, IoError> {
        if self.file.dataset(PEOPLE_GROUP).is_err() {
            return Ok(None);
        }
        self.read(PEOPLE_GROUP).map(Some)
    }

    /// When each person entered the run, by id (0 for those there at the start; NaN for
    /// those of a file written before 2026-11-28 that a run resumed); `None` for a file
    /// written before, which did not store them.
    pub fn entry_times(&self) -> Result<Option<Vec<f64>>, IoError> {
        if self.file.dataset(PEOPLE_ENTRY_TIME).is_err() {
            return Ok(None);
        }
        self.read(PEOPLE_ENTRY_TIME).map(Some)
    }

    /// The wall segments `[x0, y0, x1, y1]` (empty for a file written before they were
    /// stored).
    pub fn walls(&self) -> Result<Vec<[f64; 4]>, IoError> {
        if self.file.dataset(WALLS).is_err() {
            return Ok(Vec::new());
        }
        let flat: Vec<f64> = self.read(WALLS)?;
        Ok(flat
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect())
    }

    /// The segments `[x0, y0, x1, y1]` of the moving bodies at output frame `frame` (empty for
    /// a run without moving bodies).
    pub fn moving_walls(&self, frame: usize) -> Result<Vec<[f64; 4]>, IoError> {
        if self.file.dataset(FRAME_MOVING_WALLS).is_err() {
            return Ok(Vec::new());
        }
        let ds = self.dataset(FRAME_MOVING_WALLS)?;
        let frames = ds.shape().first().copied().unwrap_or(0);
        if frame >= frames {
            return Err(self.layout(format!("moving walls of frame {frame} of {frames}")));
        }
        let a = ds
            .read_slice::<f64, _, ndarray::Ix2>((frame, .., ..))
            .at(&self.path, || {
                format!("reading the moving walls of frame {frame}")
            })?;
        Ok(a.rows()
            .into_iter()
            .map(|r| [r[0], r[1], r[2], r[3]])
            .collect())
    }

    /// Whether the run recorded contact forces.
    pub fn has_contacts(&self) -> bool {
        self.file.dataset(CONTACTS).is_ok()
    }

    /// The `/contacts` rows (empty when the run did not record them).
    pub fn contacts(&self) -> Result<Vec<ContactRow>, IoError> {
        if !self.has_contacts() {
            return Ok(Vec::new());
        }
        self.read(CONTACTS)
    }

    /// Pressures by person id at output frame `frame` (NaN: absent), when recorded.
    pub fn pressure(&self, frame: usize) -> Result<Option<Vec<f64>>, IoError> {
        if !self.has_contacts() {
            return Ok(None);
        }
        let ds = self.dataset(FRAME_PRESSURE)?;
        let frames = ds.shape().first().copied().unwrap_or(0);
        if frame >= frames {
            return Err(self.layout(format!("pressure of frame {frame} of {frames}")));
        }
        let a = ds
            .read_slice::<f64, _, ndarray::Ix1>((frame, ..))
            .at(&self.path, || {
                format!("reading the pressure of frame {frame}")
            })?;
        Ok(Some(a.to_vec()))
    }

    /// The `/exits` rows (exit −1 in files of formats before `moreau-run/4`, which did not
    /// record it).
    pub fn exits(&self) -> Result<Vec<ExitRow>, IoError> {
        if self.names_exits() {
            return self.read(EXITS);
        }
        Ok(self
            .read::<ExitRowV3>(EXITS)?
            .into_iter()
            .map(|r| ExitRow {
                id: r.id,
                exit: -1,
                t: r.t,
            })
            .collect())
    }

    /// Whether `/exits` says which exit (format `moreau-run/4` on).
    fn names_exits(&self) -> bool {
        self.text("format")
            .is_ok_and(|f| !FORMATS_WITHOUT_EXIT.contains(&f.as_str()))
    }

    /// Every dataset with its shape, type, chunks and filters, then the root attributes
    /// (long texts shortened), as `moreau inspect` prints it.
    pub fn describe(&self) -> Result<String, IoError> {
        let mut out = String::new();
        let mut names = Vec::new();
        collect(&self.file, "", &mut names).at(&self.path, || "listing".into())?;
        let _ = writeln!(out, "datasets:");
        for name in names {
            let ds = self.dataset(&name)?;
            let dtype = ds
                .dtype()
                .and_then(|t| t.to_descriptor())
                .map(|d| describe_type(&d))
                .unwrap_or_else(|_| "?".into());
            let chunk = ds
                .chunk()
                .map_or("contiguous".into(), |c| format!("chunks {c:?}"));
            let filters: Vec<String> = ds.filters().iter().map(|f| format!("{f:?}")).collect();
            let _ = writeln!(
                out,
                "  /{name:<20} {:<14} {dtype}  [{chunk}{}]",
                format!("{:?}", ds.shape()),
                if filters.is_empty() {
                    String::new()
                } else {
                    format!(", {}", filters.join(", "))
                }
            );
            for attr in ds.attr_names().unwrap_or_default() {
                let _ = writeln!(out, "      @{attr}");
            }
        }
        let _ = writeln!(out, "attributes:");
        let mut attrs = self.file.attr_names().at(&self.path, || "listing".into())?;
        attrs.sort();
        for name in attrs {
            let value = match self.text(&name) {
                Ok(v) => shorten(&v),
                Err(_) => self
                    .file
                    .attr(&name)
                    .and_then(|a| a.read_scalar::<u64>())
                    .map_or("?".into(), |v| v.to_string()),
            };
            let _ = writeln!(out, "  @{name:<15} {value}");
        }
        Ok(out)
    }
}

fn collect(group: &hdf5::Group, prefix: &str, out: &mut Vec<String>) -> hdf5::Result<()> {
    let mut names = group.member_names()?;
    names.sort();
    for name in names {
        let full = format!("{prefix}{name}");
        if let Ok(g) = group.group(&name) {
            collect(&g, &format!("{full}/"), out)?;
        } else {
            out.push(full);
        }
    }
    Ok(())
}

fn describe_type(t: &hdf5::types::TypeDescriptor) -> String {
    use hdf5::types::TypeDescriptor as T;
    match t {
        T::Compound(c) => {
            let fields: Vec<String> = c
                .fields
                .iter()
                .map(|f| format!("{}: {}", f.name, describe_type(&f.ty)))
                .collect();
            format!("{{{}}}", fields.join(", "))
        }
        other => format!("{other}"),
    }
}

fn shorten(s: &str) -> String {
    let one_line = s.replace('\n', " ⏎ ");
    if one_line.chars().count() > 100 {
        let head: String = one_line.chars().take(97).collect();
        format!("{head}... ({} bytes)", s.len())
    } else {
        one_line
    }
}
