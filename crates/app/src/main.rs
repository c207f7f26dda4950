//! `warpbench`: parses arguments and hands them to the library (see `warpbench_app`).

use std::process::ExitCode;

use clap::Parser;
use warpbench_app::cli::{self, Command};
use warpbench_app::exit::Failure;
use warpbench_app::gui::{self, GuiArgs};

/// Landmark-based registration of two 3D medical volumes (MRI, CT), live on the GPU.
///
/// Without a subcommand it opens the workbench window: with --fixed and --moving on those volumes, otherwise on the
/// demo pair (a head CT and a head MRI).
#[derive(Debug, Parser)]
#[command(name = "warpbench", version, about, args_conflicts_with_subcommands = true)]
#[command(mut_args(warpbench_app::args::parts_need_volumes))]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    gui: GuiArgs,
}

/// Opens the workbench window (a screenshot closes it after 5 frames unless --exit-after-frames says otherwise).
fn run_gui(a: GuiArgs) -> Result<(), Failure> {
    gui::run(a.into()).map_err(Failure::Internal)
}

/// Keeps a headless command's GPU probe quiet. Mesa's Vulkan device-select layer (an implicit layer the Vulkan
/// loader runs in every process) asks the Wayland compositor which GPU drives the display whenever an instance
/// enables `VK_KHR_wayland_surface`, and wgpu enables every surface extension there is. Without `XDG_RUNTIME_DIR`
/// there is no compositor to ask, and libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set in the
/// environment." for each probe. A headless command has no display to match, so in exactly that case it turns the
/// layer off (`NODEVICE_SELECT=1`), unless the user chose a device through the layer or a compositor is reachable
/// another way.
#[allow(unsafe_code, reason = "std::env::set_var, before any thread exists (see the SAFETY comment)")]
fn quiet_headless_gpu_probe() {
    let var = |name: &str| std::env::var_os(name);
    let absolute = |name: &str| var(name).is_some_and(|v| std::path::Path::new(&v).is_absolute());
    let compositor_reachable =
        absolute("XDG_RUNTIME_DIR") || absolute("WAYLAND_DISPLAY") || var("WAYLAND_SOCKET").is_some();
    let user_chose = ["NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT", "DRI_PRIME"].into_iter().any(|v| var(v).is_some());
    if !compositor_reachable && !user_chose {
        // SAFETY: called from `run` after parsing the arguments and before anything else: no other thread exists
        // yet, so nothing reads or writes the environment at the same time.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

/// SIGINT, SIGTERM and SIGHUP in a headless command: remove the temporaries of the write in progress (so nothing
/// half-written stays beside an output), then die of the signal as if it had not been handled (a shell reports 130
/// for Ctrl-C, 143 for SIGTERM). A SIGKILL cannot be handled: the next write into that folder removes what it left
/// (`warpbench_io::atomic`).
#[cfg(unix)]
fn remove_temporaries_on_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    // Without the handler a signal kills as it always did; the next run still removes the leftovers.
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else { return };
    let handler = move || {
        if let Some(signal) = signals.forever().next() {
            warpbench_io::atomic::remove_temporaries_before_exit();
            let _ = signal_hook::low_level::emulate_default_handler(signal);
            std::process::exit(128 + signal);
        }
    };
    let _ = std::thread::Builder::new().name("signals".into()).spawn(handler);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        None => run_gui(cli.gui),
        Some(command) => run(command),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            let (code, message) = f.exit_code();
            if let Some(message) = message {
                eprintln!("warpbench: {message}");
            }
            code
        }
    }
}

/// Runs a headless subcommand, its output on stdout.
fn run(command: Command) -> Result<(), Failure> {
    quiet_headless_gpu_probe();
    #[cfg(unix)]
    remove_temporaries_on_signals();
    cli::run(command, &mut std::io::stdout().lock())
}
