//! `moreau view`: a run file to one self-contained HTML page that plays the run (the data and
//! the player inside; no server, no network).
//!
//! The page is `view/player.html` with its data line filled in: JSON whose large arrays are
//! little-endian float32 in base64 (the contract is written at the top of the player's
//! script). Runs too large to play in a browser are decimated, frames first (down to 100),
//! then people, to at most `--max-values` numbers, and the page says so.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use moreau_crowd::Scene;
use moreau_io::{Overwrite, RunFile};
use serde::Serialize;

/// The player, with [`PLACEHOLDER`] where the data goes.
const TEMPLATE: &str = include_str!("view/player.html");
/// The one line of the template replaced by the data.
const PLACEHOLDER: &str =
    r#"<script id="moreau-data" type="application/json">__MOREAU_DATA__</script>"#;

/// Arguments of `moreau view`.
#[derive(Debug, clap::Args)]
pub struct ViewArgs {
    /// The run file (HDF5).
    file: PathBuf,
    /// The HTML file to write (default: the run file with `.html`).
    #[arg(short, long, value_name = "OUT.html")]
    output: Option<PathBuf>,
    /// Replace the output file if it exists.
    #[arg(long)]
    force: bool,
    /// At most this many numbers (coordinates and pressures) in the page: larger runs are
    /// decimated, frames first (down to 100), then people.
    #[arg(long, default_value_t = 40_000_000, value_name = "N")]
    max_values: usize,
}

#[derive(Debug, Serialize)]
struct Exit {
    name: String,
    points: Vec<[f64; 2]>,
}

#[derive(Debug, Serialize)]
struct Geometry {
    area: Vec<Vec<[f64; 2]>>,
    walls: Vec<[f64; 4]>,
    exits: Vec<Exit>,
}

#[derive(Debug, Serialize)]
struct PlayerData {
    format: &'static str,
    title: String,
    people_total: usize,
    people_shown: usize,
    frames_total: usize,
    note: String,
    bbox: [f64; 4],
    geometry: Geometry,
    time: Vec<f64>,
    eps: Option<Vec<Option<f64>>>,
    violation: Option<Vec<Option<f64>>>,
    radius: String,
    positions: String,
    pressure: Option<String>,
    /// The moving walls per frame shown, `[frames][segments][4]` (absent without).
    #[serde(skip_serializing_if = "Option::is_none")]
    moving: Option<String>,
}

/// Which frames and people a page of at most `max_values` numbers shows: strides
/// `(frames, people)`. Every k-th frame, the smallest k that fits but never fewer than
/// [`MIN_FRAMES`] frames (k ≤ frames / 100); then every k-th person, the smallest k that
/// fits. The rule of `python/player_data.py`'s `strides`, which makes the same page data.
/// (Until session 38 the frame stride was rounded up from 100 frames: 150 frames kept 75.)
fn strides(frames: usize, people: usize, per_person: usize, max_values: usize) -> (usize, usize) {
    let size = |sf: usize, sp: usize| frames.div_ceil(sf) * people.div_ceil(sp) * per_person;
    if frames == 0 || people == 0 || size(1, 1) <= max_values {
        return (1, 1);
    }
    let sf_max = (frames / MIN_FRAMES).max(1);
    let keep_frames = max_values / (people * per_person);
    if keep_frames >= 1 {
        let sf = frames.div_ceil(keep_frames);
        if sf <= sf_max {
            return (sf, 1);
        }
    }
    let sf = sf_max;
    let keep_people = (max_values / (frames.div_ceil(sf) * per_person)).max(1);
    let mut sp = people.div_ceil(keep_people).max(1);
    while sp > 1 && size(sf, sp - 1) <= max_values {
        sp -= 1;
    }
    while sp < people && size(sf, sp) > max_values {
        sp += 1;
    }
    (sf, sp)
}

/// The fewest frames a decimated page keeps before it drops people.
const MIN_FRAMES: usize = 100;

/// Base64 (standard alphabet, padded) of `values` as little-endian float32.
fn base64_f32(values: &[f32]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// The exits as the player draws them: their area, or their line.
fn exits(scene: &Scene) -> Vec<Exit> {
    scene
        .exits
        .iter()
        .map(|e| Exit {
            name: e.name.clone(),
            points: match (&e.area, &e.segment) {
                (Some(area), _) => area.clone(),
                (None, Some(s)) => s.to_vec(),
                (None, None) => Vec::new(),
            },
        })
        .collect()
}

/// Builds the page's data from an open run file.
fn player_data(f: &RunFile, max_values: usize) -> Result<PlayerData> {
    let header = f.header()?;
    let scene = Scene::from_run_file(&header.scene, "the run file's attribute 'scene'")
        .context("reading the scene stored in the run file")?;
    let times = f.frame_times()?;
    let steps = f.steps()?;
    let people = header.radii.len();
    let contacts = f.has_contacts();
    let per_person = if contacts { 3 } else { 2 };
    let (frame_stride, people_stride) = strides(times.len(), people, per_person, max_values);
    let shown: Vec<usize> = (0..people).step_by(people_stride).collect();
    let frames: Vec<usize> = (0..times.len()).step_by(frame_stride).collect();

    let mut positions = Vec::with_capacity(frames.len() * shown.len() * 2);
    let mut pressure = Vec::with_capacity(if contacts {
        frames.len() * shown.len()
    } else {
        0
    });
    for &k in &frames {
        let all = f.positions(k)?;
        positions.extend(
            shown
                .iter()
                .flat_map(|&i| [all[2 * i] as f32, all[2 * i + 1] as f32]),
        );
        if let Some(p) = f.pressure(k)? {
            pressure.extend(shown.iter().map(|&i| p[i] as f32));
        }
    }
    let segments = header.moving_body.len();
    let mut moving = Vec::with_capacity(frames.len() * segments * 4);
    if segments > 0 {
        for &k in &frames {
            let walls = f.moving_walls(k)?;
            // A file whose moving walls are missing (or of another count) drew nothing and
            // said nothing (`"moving": ""`).
            if walls.len() != segments {
                bail!(
                    "frame {k} holds {} moving wall segments, /moving/body lists {segments}: a \
                     damaged run file",
                    walls.len()
                );
            }
            moving.extend(walls.iter().flatten().map(|&x| x as f32));
        }
    }
    // Per frame: the last step that ended at or before it (steps in time order, whatever
    // order the file holds them in).
    let mut steps = steps;
    steps.sort_by(|a, b| a.t.total_cmp(&b.t));
    let (mut eps, mut violation) = (Vec::new(), Vec::new());
    for &k in &frames {
        let t = times[k];
        let i = steps.partition_point(|s| s.t <= t + 1e-9 * t.abs().max(1.0));
        let last = i.checked_sub(1).map(|i| &steps[i]);
        eps.push(last.map(|s| s.eps));
        violation.push(last.map(|s| s.violation));
    }

    let mut walls = f.walls()?;
    if walls.is_empty() {
        walls = scene
            .walls()
            .iter()
            .map(|w| [w.a[0], w.a[1], w.b[0], w.b[1]])
            .collect();
    }
    let mut area = vec![scene.area.outer.clone()];
    area.extend(scene.area.holes.iter().cloned());
    let mut bbox = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let exits = exits(&scene);
    // The moving bodies as drawn, wherever they go (room-closing-door's panel starts below
    // the area and was drawn outside the view).
    let drawn: Vec<[f64; 2]> = moving
        .chunks_exact(2)
        .map(|p| [f64::from(p[0]), f64::from(p[1])])
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .collect();
    for p in area
        .iter()
        .flatten()
        .chain(exits.iter().flat_map(|e| &e.points))
        .chain(&drawn)
    {
        bbox = [
            bbox[0].min(p[0]),
            bbox[1].min(p[1]),
            bbox[2].max(p[0]),
            bbox[3].max(p[1]),
        ];
    }
    let mut note = String::new();
    if frame_stride > 1 {
        let _ = write!(note, "every {} frame", ordinal(frame_stride));
    }
    if people_stride > 1 {
        let _ = write!(
            note,
            "{}every {} person ({} of {people})",
            if note.is_empty() { "" } else { ", " },
            ordinal(people_stride),
            shown.len()
        );
    }
    if !note.is_empty() {
        note.push_str(" shown: the run is larger than --max-values");
    }
    let radius: Vec<f32> = shown.iter().map(|&i| header.radii[i] as f32).collect();
    Ok(PlayerData {
        format: "moreau-player-1",
        title: header.scene_name,
        people_total: people,
        people_shown: shown.len(),
        frames_total: times.len(),
        note,
        bbox,
        geometry: Geometry { area, walls, exits },
        time: frames.iter().map(|&k| times[k]).collect(),
        eps: Some(eps),
        violation: Some(violation),
        radius: base64_f32(&radius),
        positions: base64_f32(&positions),
        pressure: contacts.then(|| base64_f32(&pressure)),
        moving: (segments > 0).then(|| base64_f32(&moving)),
    })
}

/// The page for `data`: the template with its data line filled in.
fn page(data: &PlayerData) -> Result<String> {
    // JSON cannot end the script element early once every '<' is escaped.
    let json = serde_json::to_string(data)?.replace('<', "\\u003c");
    let line = format!(r#"<script id="moreau-data" type="application/json">{json}</script>"#);
    if TEMPLATE.matches(PLACEHOLDER).count() != 1 {
        bail!("internal: the player template lacks its data line");
    }
    Ok(TEMPLATE.replacen(PLACEHOLDER, &line, 1))
}

/// The default output: the run file with `.html`.
fn default_output(run: &Path) -> PathBuf {
    run.with_extension("html")
}

/// Runs `moreau view`.
pub fn view(args: &ViewArgs) -> Result<()> {
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| default_output(&args.file));
    // The same file by another name too (`./run.h5`, an absolute path, a link): compared as
    // text, `view run.h5 -o ./run.h5 --force` wrote the page over the run file.
    if moreau_io::same_file(&out, &args.file) {
        bail!("the output '{}' is the run file itself", out.display());
    }
    let overwrite = if args.force {
        Overwrite::Allowed
    } else {
        Overwrite::Never
    };
    moreau_io::check_output(&out, overwrite)?;
    if args.max_values < 1000 {
        bail!("--max-values {}: must be at least 1000", args.max_values);
    }
    let f = RunFile::open(&args.file)?;
    let data = player_data(&f, args.max_values)?;
    let html = page(&data)?;
    // Written beside the target and renamed over it: a failure leaves no half page.
    let partial = out.with_extension(format!("html.{}.partial", std::process::id()));
    std::fs::write(&partial, &html)
        .and_then(|()| std::fs::rename(&partial, &out))
        .inspect_err(|_| {
            let _ = std::fs::remove_file(&partial);
        })
        .with_context(|| format!("writing '{}'", out.display()))?;
    println!(
        "{}: {} frames, {} of {} people{}; wrote {} ({:.1} MB)",
        args.file.display(),
        data.time.len(),
        data.people_shown,
        data.people_total,
        if data.note.is_empty() {
            String::new()
        } else {
            format!(" ({})", data.note)
        },
        out.display(),
        html.len() as f64 / 1e6
    );
    Ok(())
}

/// `n` as an English ordinal: 2nd, 3rd, 11th, 21st (the note said "every 2th frame").
fn ordinal(n: usize) -> String {
    let suffix = match (n % 100, n % 10) {
        (11..=13, _) => "th",
        (_, 1) => "st",
        (_, 2) => "nd",
        (_, 3) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_note_said_every_2th_frame() {
        let words: Vec<String> = [1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111, 112]
            .map(ordinal)
            .into();
        assert_eq!(
            words,
            [
                "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st",
                "111th", "112th"
            ]
        );
    }

    #[test]
    fn base64_matches_the_standard_alphabet_and_padding() {
        // 1.0f32 = 00 00 80 3f; 2.0f32 = 00 00 00 40.
        assert_eq!(base64_f32(&[1.0]), "AACAPw==");
        assert_eq!(base64_f32(&[1.0, 2.0]), "AACAPwAAAEA=");
        assert_eq!(base64_f32(&[]), "");
    }

    #[test]
    fn large_runs_lose_frames_first_then_people() {
        assert_eq!(strides(200, 150, 2, 40_000_000), (1, 1));
        // 10⁶ people, 2,000 frames: 100 frames kept, then every 10th person.
        let (fs, ps) = strides(2000, 1_000_000, 2, 40_000_000);
        assert_eq!(fs, 20);
        assert!(2000usize.div_ceil(fs) * 1_000_000usize.div_ceil(ps) * 2 <= 40_000_000);
        assert_eq!(ps, 5);
        // Frames alone suffice: 1,000 frames of 100,000 people → 200 frames.
        assert_eq!(strides(1000, 100_000, 2, 40_000_000), (5, 1));
    }

    #[test]
    fn a_page_of_150_frames_kept_75_where_the_readme_says_100() {
        // 150 frames of 60 people in 17,000 values: the frame stride was 150 / 100 rounded
        // up, 2, leaving 75 frames; it is 1 (every frame, every 2nd person), as
        // player_data.py makes it.
        let (fs, ps) = strides(150, 60, 2, 17_000);
        assert_eq!((fs, ps), (1, 2));
        // 601 frames in 20,000 values: at least 100 frames.
        let (fs, ps) = strides(601, 60, 2, 20_000);
        assert!(601usize.div_ceil(fs) >= 100, "{fs}");
        assert!(601usize.div_ceil(fs) * 60usize.div_ceil(ps) * 2 <= 20_000);
    }
}
