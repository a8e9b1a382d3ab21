//! Farm jobs run for real, each against single-process renders of the same frames, bit for
//! bit (decoded EXR channels and attributes, PNG bytes):
//! - `strata farm slurm --submit` on a single-node Slurm this test starts from Debian's
//!   packages (`munged`, `slurmctld`, `slurmd`, a generated `slurm.conf` for localhost passed
//!   through `SLURM_CONF`): 3 frames × 2 splits, one task requeued while it renders, which
//!   resumes from its checkpoint;
//! - `strata farm openjd`: the template passes `openjd check` and `openjd run` runs it.
//!
//! They need root (the daemons), Slurm and munge (`apt-get install slurm-wlm munge`), and
//! `openjd` from PyPI (`openjd-cli`; `$OPENJD`, `.ci/venv-openjd/bin/openjd` or on the
//! PATH). `.ci/run` installs them; under CI (`$CI` set) a missing tool fails the test,
//! elsewhere the test prints why it skips.

mod common;

use common::decode;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/in/farm/shot.usda");
const RENDER_ARGS: [&str; 4] = ["--res", "24x18", "--threads", "1"];
/// The Slurm test renders long enough that a task can be requeued while it renders.
const SLURM_RENDER_ARGS: [&str; 4] = ["--res", "128x96", "--threads", "1"];

/// Skips (returns) with a printed reason outside CI; fails under CI.
macro_rules! require {
    ($found:expr) => {
        match $found {
            Ok(found) => found,
            Err(reason) if std::env::var_os("CI").is_none() => {
                eprintln!("skipped: {reason}");
                return;
            }
            Err(reason) => panic!("{reason} (CI is set: the tool must be there; .ci/run installs it)"),
        }
    };
}

/// The path of `name` in `/usr/sbin`, `/usr/bin` or the PATH.
fn tool(name: &str) -> Result<PathBuf, String> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    ["/usr/sbin", "/usr/bin"]
        .into_iter()
        .map(PathBuf::from)
        .chain(std::env::split_paths(&path))
        .map(|dir| dir.join(name))
        .find(|p| p.is_file())
        .ok_or_else(|| format!("`{name}` is not installed (apt-get install slurm-wlm munge)"))
}

fn run(command: &mut Command) -> std::process::Output {
    let out = command.stdin(Stdio::null()).output().unwrap_or_else(|e| panic!("{command:?}: {e}"));
    assert!(
        out.status.success(),
        "{command:?}: {}\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Renders frames `frames` of the scene in one process, named `ref/shot.####.exr` under `dir`.
fn single_run(dir: &Path, scene: &str, frames: &str, spp: u32, render_args: &[&str]) {
    std::fs::create_dir_all(dir.join("ref")).unwrap();
    let spp = spp.to_string();
    let mut args = vec!["render", scene, "--frames", frames, "--spp", &spp, "-o", "ref/shot.####.exr"];
    args.extend(render_args);
    run(Command::new(env!("CARGO_BIN_EXE_strata")).args(&args).current_dir(dir));
}

/// Each merged frame `out/shot.####.exr` equals the single run's `ref/shot.####.exr`.
fn assert_frames_equal(dir: &Path, frames: &[i64]) {
    for frame in frames {
        let file = |kind: &str, ext: &str| dir.join(kind).join(format!("shot.{frame:04}.{ext}"));
        let merged = decode(&file("out", "exr"));
        assert_eq!(merged.attributes.get("strata/frame"), Some(&frame.to_string()));
        assert!(merged == decode(&file("ref", "exr")), "frame {frame}: the merged EXR differs");
        let png = |kind: &str| std::fs::read(file(kind, "png")).unwrap();
        assert!(png("out") == png("ref"), "frame {frame}: the merged PNG differs");
    }
}

/// A daemon this test started: killed (SIGKILL: its state is a temporary directory, and a
/// clean `slurmctld` shutdown takes seconds) and reaped when dropped.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A port nobody listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn wait_for(what: &str, deadline: Duration, mut ready: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ready() {
        assert!(start.elapsed() < deadline, "{what} did not happen within {deadline:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A single-node Slurm on localhost: munged (as the munge user), slurmctld and slurmd, all
/// in `root` (mode 0755, so the munge user reaches its socket directory).
struct Slurm {
    conf: PathBuf,
    // Dropped in reverse: slurmd, slurmctld, then munged.
    _daemons: Vec<Daemon>,
}

impl Slurm {
    fn start(root: &Path) -> Result<Slurm, String> {
        // SAFETY: geteuid(2) has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return Err("starting slurmctld, slurmd and munged needs root".into());
        }
        let (munged, mungekey, slurmctld, slurmd) =
            (tool("munged")?, tool("mungekey")?, tool("slurmctld")?, tool("slurmd")?);
        tool("sbatch")?;
        let chmod = |p: &Path, mode: u32| {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
        };
        chmod(root, 0o755);
        let munge = root.join("munge");
        for sub in ["munge", "state", "spool"] {
            std::fs::create_dir(root.join(sub)).unwrap();
        }
        run(Command::new("chown").args(["munge:munge", munge.to_str().unwrap()]));
        chmod(&munge, 0o755);
        // The munge user's IDs: munged refuses to run as root, and runs as the child itself
        // (not under runuser), so killing the child stops it.
        let id = |flag: &str| -> u32 {
            let out = run(Command::new("id").args([flag, "munge"]));
            String::from_utf8_lossy(&out.stdout).trim().parse().expect("a numeric ID")
        };
        let (uid, gid) = (id("-u"), id("-g"));
        let as_munge = |program: &Path| {
            use std::os::unix::process::CommandExt;
            let mut command = Command::new(program);
            command.uid(uid).gid(gid);
            command
        };
        let key = munge.join("munge.key");
        run(as_munge(&mungekey).arg("--create").arg(format!("--keyfile={}", key.display())));
        let socket = munge.join("munge.socket");
        let mut daemons = vec![Daemon(
            as_munge(&munged)
                .arg("--foreground")
                .arg(format!("--socket={}", socket.display()))
                .arg(format!("--key-file={}", key.display()))
                .arg(format!("--log-file={}", munge.join("munged.log").display()))
                .arg(format!("--pid-file={}", munge.join("munged.pid").display()))
                .arg(format!("--seed-file={}", munge.join("munged.seed").display()))
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        )];
        wait_for("munged's socket", Duration::from_secs(10), || socket.exists());

        let r = root.display();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let conf = root.join("slurm.conf");
        std::fs::write(
            &conf,
            format!(
                "ClusterName=strata\nSlurmctldHost=localhost\nSlurmUser=root\nSlurmdUser=root\n\
                 SlurmctldPort={}\nSlurmdPort={}\n\
                 AuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={}\n\
                 StateSaveLocation={r}/state\nSlurmdSpoolDir={r}/spool\n\
                 SlurmctldPidFile={r}/slurmctld.pid\nSlurmdPidFile={r}/slurmd.pid\n\
                 SlurmctldLogFile={r}/slurmctld.log\nSlurmdLogFile={r}/slurmd.log\n\
                 ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nMailProg=/bin/true\n\
                 JobCompType=jobcomp/none\nAccountingStorageType=accounting_storage/none\n\
                 JobAcctGatherType=jobacct_gather/none\n\
                 SchedulerType=sched/backfill\nSelectType=select/cons_tres\nSelectTypeParameters=CR_CPU\n\
                 ReturnToService=2\n\
                 NodeName=localhost NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN\n\
                 PartitionName=strata Nodes=localhost Default=YES MaxTime=INFINITE State=UP\n",
                free_port(),
                free_port(),
                socket.display()
            ),
        )
        .unwrap();
        let daemon = |program: &Path, args: &[&str]| {
            let log =
                std::fs::File::create(root.join(format!("{}.out", program.file_name().unwrap().display()))).unwrap();
            Daemon(
                Command::new(program)
                    .args(args)
                    .env("SLURM_CONF", &conf)
                    .stdin(Stdio::null())
                    .stdout(log.try_clone().unwrap())
                    .stderr(log)
                    .spawn()
                    .unwrap(),
            )
        };
        daemons.push(daemon(&slurmctld, &["-D", "-i"]));
        daemons.push(daemon(&slurmd, &["-D", "-N", "localhost"]));
        let slurm = Slurm { conf, _daemons: daemons };
        wait_for("the node to come up idle", Duration::from_secs(30), || {
            slurm.scontrol(&["show", "node", "localhost"]).is_some_and(|s| s.contains("State=IDLE"))
        });
        Ok(slurm)
    }

    /// `scontrol ARGS…`'s output, `None` when it fails (the controller not up yet).
    fn scontrol(&self, args: &[&str]) -> Option<String> {
        let out = Command::new("scontrol").args(args).env("SLURM_CONF", &self.conf).output().ok()?;
        out.status.success().then(|| String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// Every `JobState=` of a job (one per array task).
    fn states(&self, job: &str) -> Vec<String> {
        let text = self.scontrol(&["show", "job", job]).unwrap_or_default();
        text.split_whitespace().filter_map(|w| w.strip_prefix("JobState=")).map(String::from).collect()
    }
}

#[test]
fn a_slurm_array_of_frames_by_splits_merges_into_single_process_renders() {
    let root = tempfile::tempdir().unwrap();
    let slurm = require!(Slurm::start(root.path()));
    let work = root.path().join("work");
    std::fs::create_dir(&work).unwrap();
    // 3 frames × 2 splits; 2-sample checkpoints, so a task holds a checkpoint while it renders.
    // An array limit of 2 splits the frames into chunks 1-2 and 3: 4 render arrays, 2 merges.
    let spp = 64;
    let mut args = vec!["farm", "slurm", SCENE, "--frames", "1-3", "--split-samples", "2", "--spp", "64"];
    args.extend(["--checkpoint", "2", "--max-array-size", "2", "-o", "out/shot.####.exr", "--submit", "--"]);
    args.extend(SLURM_RENDER_ARGS);
    let out =
        run(Command::new(env!("CARGO_BIN_EXE_strata")).args(&args).current_dir(&work).env("SLURM_CONF", &slurm.conf));
    let printed = String::from_utf8(out.stdout).unwrap();
    let arrays: Vec<(&str, &str)> = printed.lines().filter_map(|l| l.split_once(' ')).collect();
    let kinds: Vec<&str> = arrays.iter().map(|a| a.0).collect();
    assert_eq!(kinds, ["render", "render", "merge", "render", "render", "merge"], "{printed}");
    let of = |kind: &str| arrays.iter().filter(|a| a.0 == kind).map(|a| a.1.to_string()).collect::<Vec<_>>();
    let (renders, merges) = (of("render"), of("merge"));
    let render = renders[0].as_str();
    // Each merge array waits on its own chunk's render arrays only (`aftercorr`: task by task);
    // the first chunk's renders take seconds, so its merge still waits on both.
    let after = |merge: &str| -> Vec<String> {
        let text = slurm.scontrol(&["show", "job", merge]).unwrap_or_default();
        let field = text.split_whitespace().find_map(|w| w.strip_prefix("Dependency=")).unwrap_or("").to_string();
        // `aftercorr:A_*(state):B_*(state)` or one `aftercorr:` per job, joined by commas.
        let ids = field.split(',').filter_map(|d| d.strip_prefix("aftercorr:")).flat_map(|d| d.split(':'));
        ids.map(|id| id.chars().take_while(char::is_ascii_digit).collect()).collect()
    };
    let mut first = after(&merges[0]);
    first.sort();
    assert_eq!(first, [renders[0].clone(), renders[1].clone()], "merge {}", merges[0]);
    assert!(after(&merges[1]).iter().all(|id| renders[2..].contains(id)), "merge {}", merges[1]);
    let job_dir = work.join("out/shot.farm");
    assert!(job_dir.join("submit.sh").is_file() && job_dir.join("render.sbatch").is_file());

    // Requeue task 0 once it has written a checkpoint: rerun, it must resume from it.
    let checkpoint = job_dir.join("parts/shot.0001.part0.checkpoint.exr");
    wait_for("task 0's first checkpoint", Duration::from_secs(120), || {
        checkpoint.exists() || slurm.states(&format!("{render}_0")).iter().any(|s| s != "PENDING" && s != "RUNNING")
    });
    let task0 = format!("{render}_0");
    // Task 0 writes 16 checkpoints over seconds: it cannot end between two polls.
    let requeued = checkpoint.exists() && slurm.scontrol(&["requeue", &task0]).is_some();
    assert!(requeued, "task 0 ended before it could be requeued: {:?}", slurm.states(&task0));
    {
        // Slurm holds a requeued job back about two minutes; let it start again now.
        wait_for("the requeued task to be eligible", Duration::from_secs(30), || {
            slurm.states(&task0) == ["PENDING"]
                && slurm.scontrol(&["update", &format!("JobId={task0}"), "StartTime=now"]).is_some()
        });
    }

    let logs = || {
        let mut text = String::new();
        for entry in std::fs::read_dir(job_dir.join("logs")).into_iter().flatten().flatten() {
            text += &format!(
                "--- {}\n{}",
                entry.path().display(),
                std::fs::read_to_string(entry.path()).unwrap_or_default()
            );
        }
        text
    };
    wait_for("the merge jobs to finish", Duration::from_secs(600), || {
        let states: Vec<String> = merges.iter().flat_map(|m| slurm.states(m)).collect();
        let failed = states
            .iter()
            .any(|s| ["FAILED", "CANCELLED", "TIMEOUT", "NODE_FAIL", "OUT_OF_MEMORY"].contains(&s.as_str()));
        assert!(!failed, "merge jobs {merges:?}: {states:?}\n{}", logs());
        states.len() == 3 && states.iter().all(|s| s == "COMPLETED")
    });
    for r in &renders {
        assert!(slurm.states(r).iter().all(|s| s == "COMPLETED"));
    }
    let log = logs();
    assert!(log.contains("resuming from"), "the requeued task did not resume:\n{log}");
    single_run(&work, SCENE, "1-3", spp, &SLURM_RENDER_ARGS);
    assert_frames_equal(&work, &[1, 2, 3]);
}

/// `openjd`: `$OPENJD`, the venv `.ci/run` makes, or on the PATH.
fn openjd() -> Result<PathBuf, String> {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/venv-openjd/bin/openjd");
    let on_path = || tool("openjd").ok();
    std::env::var_os("OPENJD")
        .map(PathBuf::from)
        .or_else(|| venv.is_file().then_some(venv))
        .or_else(on_path)
        .ok_or_else(|| "`openjd` is not installed (pip install openjd-cli; or set OPENJD)".into())
}

#[test]
fn an_openjd_template_checks_and_runs_into_single_process_renders() {
    let openjd = require!(openjd());
    let root = tempfile::tempdir().unwrap();
    let work = root.path();
    let mut args = vec!["farm", "openjd", SCENE, "--frames", "1-3x2", "--split-samples", "3", "--spp", "7"];
    args.extend(["-o", "out/shot.####.exr", "--dir", "job", "--"]);
    args.extend(RENDER_ARGS);
    let out = run(Command::new(env!("CARGO_BIN_EXE_strata")).args(&args).current_dir(work));
    let template = PathBuf::from(String::from_utf8(out.stdout).unwrap().trim());
    assert_eq!(template, work.join("job/job.template.json"));
    run(Command::new(&openjd).arg("check").arg(&template));
    run(Command::new(&openjd).arg("run").arg(&template).current_dir(work));
    single_run(work, SCENE, "1-3x2", 7, &RENDER_ARGS);
    assert_frames_equal(work, &[1, 3]);
    assert!(!work.join("out/shot.0002.exr").exists());
}
