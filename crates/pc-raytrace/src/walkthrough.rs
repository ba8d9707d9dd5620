//! Walkthroughs: frames of the config's camera orbiting its target, rendered on the cached
//! solution (the seed's interactive walkthrough, §10, as a fixed path).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::sync::Mutex;
use std::time::Instant;

use pc_config::{Backend, LoadedConfig};
use pc_stage::Progress;

use crate::camera::Camera;
use crate::error::RenderError;
use crate::image::{write_png, Image};
use crate::renderer::{Device, Renderer};
use crate::stage::{with_scene, Inputs};

/// The camera of frame `i` of `frames` on the walkthrough path: the config's camera orbiting
/// its target about its up axis, from −`orbit_deg`/2 to +`orbit_deg`/2, at the same distance
/// and field of view (the seed's interactive walkthrough, §10, as a fixed path).
pub fn walkthrough_camera(
    base: &pc_config::CameraConfig,
    i: usize,
    frames: usize,
    orbit_deg: f32,
) -> pc_config::CameraConfig {
    use glam::{Quat, Vec3};
    let t = if frames > 1 {
        i as f32 / (frames - 1) as f32
    } else {
        0.5
    };
    let angle = (t - 0.5) * orbit_deg.to_radians();
    let target = Vec3::from(base.target);
    let up = Vec3::from(base.up).normalize_or_zero();
    let offset = Vec3::from(base.origin) - target;
    let origin = target + Quat::from_axis_angle(up, angle) * offset;
    pc_config::CameraConfig {
        origin: origin.into(),
        ..base.clone()
    }
}

/// What a walkthrough made.
pub struct Walkthrough {
    pub frames: Vec<PathBuf>,
    pub device: Device,
    pub device_name: String,
    /// Time spent rendering the frames (loading and GPU setup excluded).
    pub render_seconds: f64,
    /// Time spent writing the PNGs, summed over the writer threads beside the rendering.
    pub write_seconds: f64,
    /// From the first frame's start to the last frame written.
    pub frames_seconds: f64,
    /// Loading the artifacts and setting up the renderer.
    pub setup_seconds: f64,
}

/// Where and how a walkthrough goes.
#[derive(Clone, Debug)]
pub struct Orbit {
    /// The folder of the frames (`frame_00000.png`, ...).
    pub dir: PathBuf,
    pub frames: usize,
    /// The orbit's angle, in degrees, centred on the config's camera.
    pub degrees: f32,
}

/// Render the frames of `orbit` along [`walkthrough_camera`]'s path on the cached solution (the
/// artifacts are loaded once; the GPU keeps its buffers between frames), each PNG written
/// atomically by one of [`png_writers`] threads while the next frames render ([`with_writers`]);
/// `frame_done` hears of each frame rendered.
pub fn walkthrough(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    backend: Backend,
    orbit: &Orbit,
    frame_done: &mut dyn FnMut(usize),
) -> Result<Walkthrough, RenderError> {
    if orbit.frames == 0 {
        return Err(RenderError::NoFrames);
    }
    pc_stage::look_early(backend, pc_stage::Work::Render);
    let c = &cfg.config;
    let started = Instant::now();
    with_scene(cfg, inputs, backend, |sc, _, _| {
        let mut renderer = Renderer::new(sc, backend)?;
        let setup_seconds = started.elapsed().as_secs_f64();
        let mut render_seconds = 0.0;
        let paths: Vec<PathBuf> = (0..orbit.frames)
            .map(|i| orbit.dir.join(format!("frame_{i:05}.png")))
            .collect();
        let frames_started = Instant::now();
        let (rendered, written) = with_writers(c.raytrace.exposure, |writers| {
            for (i, path) in paths.iter().enumerate() {
                if writers.failed() {
                    break; // the writers' error says why
                }
                let cam = walkthrough_camera(&c.camera, i, orbit.frames, orbit.degrees);
                sc.set_camera(&Camera::new(&cam));
                let t = Instant::now();
                let image = renderer.render(sc, false, &|| {})?.image;
                render_seconds += t.elapsed().as_secs_f64();
                writers.send(i, path, image);
                frame_done(i);
            }
            Ok::<(), RenderError>(())
        });
        rendered?;
        let write_seconds = written?;
        let frames_seconds = frames_started.elapsed().as_secs_f64();
        Ok(Walkthrough {
            frames: paths,
            device: renderer.device(),
            device_name: renderer.device_name(),
            render_seconds,
            write_seconds,
            frames_seconds,
            setup_seconds,
        })
    })
}

/// One rendered frame on its way to a writer: its number, its PNG's path, the image.
type Frame<'p> = (usize, &'p Path, Image);

/// Where `render` ([`with_writers`]) hands its frames.
struct Writers<'p, 'w> {
    tx: std::sync::mpsc::SyncSender<Frame<'p>>,
    failed: &'w AtomicBool,
}

impl<'p> Writers<'p, '_> {
    /// Whether a writer has failed: the frames after it would not be written.
    fn failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }

    /// Hands frame `i` to a writer, waiting while as many frames wait as there are writers.
    fn send(&self, i: usize, path: &'p Path, image: Image) {
        // The writers take frames until the sender is dropped, so the channel stays open.
        let _ = self.tx.send((i, path, image));
    }
}

/// Runs `render` with [`png_writers`] threads writing the frames it hands to [`Writers`] as
/// PNGs (atomically, at the exposure given); returns what `render` returned and the writers'
/// summed seconds, or the error of the earliest frame that failed ([`first_error`]).
fn with_writers<'p, R>(
    exposure: f32,
    render: impl FnOnce(&Writers<'p, '_>) -> R,
) -> (R, Result<f64, RenderError>) {
    let n = png_writers();
    let (tx, rx) = std::sync::mpsc::sync_channel::<Frame<'p>>(n);
    let rx = Mutex::new(rx);
    let failed = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..n)
            .map(|_| scope.spawn(|| write_frames(&rx, &failed, exposure)))
            .collect();
        let writers = Writers {
            tx,
            failed: &failed,
        };
        let out = render(&writers);
        drop(writers); // the writers stop once the channel is empty
        let written = handles.into_iter().map(|h| {
            h.join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
        });
        (out, first_error(written))
    })
}

/// One writer thread: writes the frames it takes from `rx` until the channel closes; its
/// seconds spent writing and its first failure (frame and error). After a failure it sets
/// `failed` and keeps taking frames (dropping them) until the renderer, seeing `failed`, stops
/// sending: a writer that returned could leave the renderer blocked on a full channel with no
/// one to empty it.
fn write_frames(
    rx: &Mutex<Receiver<Frame<'_>>>,
    failed: &AtomicBool,
    exposure: f32,
) -> (f64, Option<(usize, RenderError)>) {
    let mut seconds = 0.0;
    let mut error = None;
    loop {
        let next = rx.lock().unwrap_or_else(|e| e.into_inner()).recv();
        let Ok((i, path, image)) = next else {
            return (seconds, error);
        };
        if error.is_some() {
            continue;
        }
        let t = Instant::now();
        match write_png(path, &image, exposure) {
            Ok(()) => seconds += t.elapsed().as_secs_f64(),
            Err(e) => {
                failed.store(true, Ordering::Relaxed);
                error = Some((i, e.into()));
            }
        }
    }
}

/// Threads that write a walkthrough's PNGs: one a frame at once, up to 4 (a 1024² frame's sRGB
/// encoding and compression took 28 ms on one core of the H200's host, three times its render).
pub fn png_writers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().clamp(1, 4))
}

/// The writers' summed seconds, or the error of the earliest frame that failed.
fn first_error(
    written: impl Iterator<Item = (f64, Option<(usize, RenderError)>)>,
) -> Result<f64, RenderError> {
    let mut seconds = 0.0;
    let mut first: Option<(usize, RenderError)> = None;
    for (s, e) in written {
        seconds += s;
        if let Some((i, e)) = e {
            if first.as_ref().is_none_or(|(j, _)| i < *j) {
                first = Some((i, e));
            }
        }
    }
    match first {
        Some((_, e)) => Err(e),
        None => Ok(seconds),
    }
}

/// A walkthrough as the binary runs it: a progress bar (hidden when `quiet`), the frames, the
/// stats as JSON at `stats_json` when given; returns the summary line.
pub fn run(
    cfg: &LoadedConfig,
    inputs: &Inputs,
    backend: Backend,
    orbit: &Orbit,
    quiet: bool,
    stats_json: Option<&Path>,
) -> Result<String, RenderError> {
    let bar = pc_stage::progress::Bar::new(crate::stage::STAGE, quiet);
    bar.phase("walkthrough frames");
    bar.total(orbit.frames as u64);
    let w = walkthrough(cfg, inputs, backend, orbit, &mut |_| bar.advance(1));
    bar.finish();
    let w = w?;
    let c = &cfg.config;
    let fps = orbit.frames as f64 / w.render_seconds.max(1e-9);
    if let Some(path) = stats_json {
        let json = serde_json::json!({
            "frames": orbit.frames,
            "width": c.camera.width,
            "height": c.camera.height,
            "spp": c.raytrace.spp,
            "device": w.device_name,
            "gpu": w.device == Device::Gpu,
            "render_seconds": w.render_seconds,
            "write_seconds": w.write_seconds,
            "frames_seconds": w.frames_seconds,
            "setup_seconds": w.setup_seconds,
            "frames_per_second": fps,
            "gpu_times": pc_gpu::times().map(|t| t.json()),
        });
        pc_artifact::write_file_atomically(path, format!("{json}\n").as_bytes()).map_err(
            |source| RenderError::Io {
                path: path.to_path_buf(),
                source,
            },
        )?;
    }
    Ok(format!(
        "pc-raytrace: wrote {} frames to {} ({}x{}, {} spp, {:.0}° orbit): {fps:.2} frames/s rendering on {}, {:.2} frames/s with the PNGs written beside (setup {:.2} s, PNG writing {:.2} s)",
        orbit.frames,
        orbit.dir.display(),
        c.camera.width,
        c.camera.height,
        c.raytrace.spp,
        orbit.degrees,
        w.device_name,
        orbit.frames as f64 / w.frames_seconds.max(1e-9),
        w.setup_seconds,
        w.write_seconds
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The writers' seconds add up, and where several writers failed the error is the earliest
    /// frame's, whichever writer met it.
    #[test]
    fn the_earliest_failed_frame_is_reported() {
        let io = |frame: &str| RenderError::Io {
            path: PathBuf::from(frame),
            source: std::io::Error::other("disk full"),
        };
        let ok = first_error([(1.0, None), (0.5, None)].into_iter()).unwrap();
        assert_eq!(ok, 1.5);
        let e = first_error(
            [
                (1.0, Some((5, io("frame_00005.png")))),
                (0.5, None),
                (2.0, Some((3, io("frame_00003.png")))),
            ]
            .into_iter(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("frame_00003.png"), "{e}");
    }
}
