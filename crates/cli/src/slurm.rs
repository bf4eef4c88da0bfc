//! `bvhlab slurm`: writes (and with `--submit` submits) an sbatch job array whose task i runs
//! `bvhlab sweep EXP --shard i/N` against one shared cache, plus a report job that depends on the
//! array (`afterany`, so it also runs when tasks failed or were cancelled) and builds the report
//! from the cache with `--report-only`. Slurm is the scheduler: job arrays, dependencies, requeue
//! and scancel are its; bvhlab only partitions the plan (`--shard`) and keeps the cache safe for
//! concurrent writers on a shared filesystem. Resubmitting the same command computes only what is
//! missing, because every shard skips cached nodes.
use bvhlab_pipeline::{Error, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What `bvhlab slurm` was asked for (the CLI's flags).
pub struct SlurmArgs {
    pub experiment: PathBuf,
    pub tasks: u32,
    pub cache: PathBuf,
    pub partition: Option<String>,
    pub time: Option<String>,
    pub constraint: Option<String>,
    pub account: Option<String>,
    /// Memory per task (sbatch `--mem`, e.g. `4G`); default from the memory estimate.
    pub mem: Option<String>,
    pub cpus_per_task: u32,
    /// Where the scripts and task logs go (default `reports/<name>/slurm`).
    pub dir: Option<PathBuf>,
    /// Report directory (default `reports/<name>`).
    pub out: Option<PathBuf>,
    /// Extra `#SBATCH` lines' arguments, e.g. `--qos=short` (repeatable).
    pub sbatch_args: Vec<String>,
    pub submit: bool,
    /// `--max-configs` the experiment was accepted with; the tasks get the same.
    pub max_configs: u64,
}

/// Values of the scripts that do not come from the flags directly.
pub struct Derived {
    pub name: String,
    /// Estimated peak memory of the largest chain (bytes), if any scene's size is known.
    pub peak_bytes: Option<u64>,
    /// The largest shard's estimated seconds, if known (printed as advice for `--time`).
    pub max_shard_seconds: Option<f64>,
}

fn abs(p: &Path) -> Result<PathBuf> {
    let p = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .map_err(|e| Error::internal(format!("current dir: {e}")))?
            .join(p)
    };
    // Canonical when it exists (symlinks resolved as every node of the cluster will see them).
    Ok(p.canonicalize().unwrap_or(p))
}

/// Single-quotes a word for bash.
fn sh(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-=:,+@%".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// `--mem` in MiB: the estimate plus 25% and 256 MiB of headroom (the estimate is calibrated
/// against peak RSS, rounded up by ~20%), at least 1 GiB; 4 GiB when no scene's size is known.
pub fn default_mem_mib(peak_bytes: Option<u64>) -> u64 {
    match peak_bytes {
        Some(b) => ((b as f64 * 1.25) as u64 / (1 << 20) + 256).max(1024),
        None => 4096,
    }
}

/// A Slurm memory size (`4G`, `512M`, `1024`: MiB as sbatch reads it) in bytes, for `--max-memory`.
fn slurm_mem_bytes(s: &str) -> Result<u64> {
    let t = s.trim();
    let (num, mult) = match t.chars().last() {
        Some('K' | 'k') => (&t[..t.len() - 1], 1u64 << 10),
        Some('M' | 'm') => (&t[..t.len() - 1], 1 << 20),
        Some('G' | 'g') => (&t[..t.len() - 1], 1 << 30),
        Some('T' | 't') => (&t[..t.len() - 1], 1 << 40),
        _ => (t, 1 << 20),
    };
    num.parse::<u64>()
        .ok()
        .filter(|&n| n > 0)
        .map(|n| n * mult)
        .ok_or_else(|| {
            Error::input(format!(
                "--mem `{s}`: expected a size like 4G, 512M or 2048 (MiB)"
            ))
        })
}

pub struct Scripts {
    pub dir: PathBuf,
    pub array: PathBuf,
    pub report: PathBuf,
    pub logs: PathBuf,
    pub out: PathBuf,
    pub mem: String,
}

/// Writes `array.sbatch` and `report.sbatch` (and creates the log directory).
pub fn write_scripts(a: &SlurmArgs, d: &Derived) -> Result<Scripts> {
    if a.tasks == 0 {
        return Err(Error::input("--tasks must be at least 1"));
    }
    if a.cpus_per_task == 0 {
        return Err(Error::input("--cpus-per-task must be at least 1"));
    }
    let exe = std::env::current_exe().map_err(|e| Error::internal(format!("own binary: {e}")))?;
    let exe = abs(&exe)?;
    let exp = abs(&a.experiment)?;
    std::fs::create_dir_all(&a.cache).map_err(|e| {
        Error::input(format!(
            "{}: cannot create cache dir: {e}",
            a.cache.display()
        ))
    })?;
    let cache = abs(&a.cache)?;
    let cwd = abs(Path::new("."))?;
    let out = abs(&a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("reports").join(&d.name)))?;
    let dir = abs(&a.dir.clone().unwrap_or_else(|| out.join("slurm")))?;
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs)
        .map_err(|e| Error::input(format!("{}: cannot create: {e}", logs.display())))?;
    let mem = match &a.mem {
        Some(m) => {
            slurm_mem_bytes(m)?;
            m.clone()
        }
        None => format!("{}M", default_mem_mib(d.peak_bytes)),
    };
    let mem_bytes = slurm_mem_bytes(&mem)?;

    let header = |job: &str, cpus: u32, mem: &str, extra: &[String]| {
        let mut h = vec!["#!/bin/bash".to_string()];
        h.push(format!("#SBATCH --job-name={}", sh(job)));
        h.extend(extra.iter().cloned());
        h.push(format!("#SBATCH --cpus-per-task={cpus}"));
        h.push(format!("#SBATCH --mem={mem}"));
        h.push(format!("#SBATCH --chdir={}", sh(&cwd.to_string_lossy())));
        if let Some(p) = &a.partition {
            h.push(format!("#SBATCH --partition={}", sh(p)));
        }
        if let Some(t) = &a.time {
            h.push(format!("#SBATCH --time={}", sh(t)));
        }
        // Pin the CPU model (e.g. a node feature): timings of different models are never mixed
        // in one plot, but pinning keeps a study on one model.
        if let Some(c) = &a.constraint {
            h.push(format!("#SBATCH --constraint={}", sh(c)));
        }
        if let Some(acc) = &a.account {
            h.push(format!("#SBATCH --account={}", sh(acc)));
        }
        for s in &a.sbatch_args {
            h.push(format!("#SBATCH {s}"));
        }
        h.join("\n")
    };
    let job = format!("bvhlab-{}", d.name);
    let logs_s = logs.to_string_lossy().to_string();
    let array_extra = vec![
        format!("#SBATCH --array=1-{}", a.tasks),
        format!(
            "#SBATCH --output={}",
            sh(&format!("{logs_s}/task-%A_%a.out"))
        ),
        // A preempted or failed node's task runs again; the cache makes that cheap.
        "#SBATCH --requeue".to_string(),
        "#SBATCH --open-mode=append".to_string(),
    ];
    let array = format!(
        "{}\n\
         # Shard SLURM_ARRAY_TASK_ID of {n} of the experiment's stage graph against the shared cache.\n\
         # Written by `bvhlab slurm`; resubmitting computes only what is missing.\n\
         set -euo pipefail\n\
         exec {exe} sweep {exp} --cache {cache} --shard \"${{SLURM_ARRAY_TASK_ID}}/{n}\" \\\n    \
         --threads \"${{SLURM_CPUS_PER_TASK:-{cpus}}}\" --max-memory {mem_bytes} --max-configs {mc}\n",
        header(&job, a.cpus_per_task, &mem, &array_extra),
        n = a.tasks,
        exe = sh(&exe.to_string_lossy()),
        exp = sh(&exp.to_string_lossy()),
        cache = sh(&cache.to_string_lossy()),
        cpus = a.cpus_per_task,
        mc = a.max_configs,
    );
    let report_extra = vec![format!(
        "#SBATCH --output={}",
        sh(&format!("{logs_s}/report-%j.out"))
    )];
    let report = format!(
        "{}\n\
         # Builds {out} from the cache once the array has ended (afterany). Exit 3: some chains\n\
         # are missing (tasks failed or were cancelled): resubmit the same `bvhlab slurm` command.\n\
         set -euo pipefail\n\
         exec {exe} sweep {exp} --cache {cache} --report-only --out {out} --max-configs {mc}\n",
        header(&format!("{job}-report"), 1, "2G", &report_extra),
        exe = sh(&exe.to_string_lossy()),
        exp = sh(&exp.to_string_lossy()),
        cache = sh(&cache.to_string_lossy()),
        out = sh(&out.to_string_lossy()),
        mc = a.max_configs,
    );
    let array_path = dir.join("array.sbatch");
    let report_path = dir.join("report.sbatch");
    for (p, text) in [(&array_path, &array), (&report_path, &report)] {
        std::fs::write(p, text)
            .map_err(|e| Error::input(format!("{}: cannot write: {e}", p.display())))?;
    }
    Ok(Scripts {
        dir,
        array: array_path,
        report: report_path,
        logs,
        out,
        mem,
    })
}

/// Runs `sbatch --parsable ARGS SCRIPT` and returns the job id.
pub fn sbatch(script: &Path, args: &[String]) -> Result<String> {
    let o = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .arg(script)
        .output()
        .map_err(|e| {
            Error::input(format!(
                "cannot run sbatch ({e}): is Slurm installed here? Without --submit the scripts are only written \
                 (see {})",
                script.display()
            ))
        })?;
    if !o.status.success() {
        return Err(Error::input(format!(
            "sbatch {} failed: {}",
            script.display(),
            String::from_utf8_lossy(&o.stderr).trim()
        )));
    }
    // `--parsable` prints `jobid` or `jobid;cluster`.
    let out = String::from_utf8_lossy(&o.stdout);
    let id = out.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.chars().all(|c| c.is_ascii_digit()) {
        return Err(Error::internal(format!(
            "sbatch printed no job id: `{}`",
            out.trim()
        )));
    }
    Ok(id)
}

/// Writes the scripts, submits them if asked, prints what to do next (stderr) and the JSON
/// summary (stdout, last line).
pub fn run(a: &SlurmArgs, d: &Derived) -> Result<()> {
    let s = write_scripts(a, d)?;
    let exp = abs(&a.experiment)?;
    let cache = abs(&a.cache)?;
    let status = format!(
        "bvhlab sweep {} --cache {} --status --shards {}",
        sh(&exp.to_string_lossy()),
        sh(&cache.to_string_lossy()),
        a.tasks
    );
    eprintln!("wrote {} and {}", s.array.display(), s.report.display());
    eprintln!(
        "  {} tasks, --mem={} per task, logs in {}",
        a.tasks,
        s.mem,
        s.logs.display()
    );
    if let Some(t) = d.max_shard_seconds {
        eprintln!(
            "  largest shard estimated at {:.0} s of compute on the machine the estimate was calibrated on{}",
            t,
            if a.time.is_none() { " (no --time given: the partition's default limit applies)" } else { "" }
        );
    }
    let (mut array_job, mut report_job) = (None, None);
    if a.submit {
        let id = sbatch(&s.array, &[])?;
        let rid = sbatch(&s.report, &[format!("--dependency=afterany:{id}")])?;
        eprintln!(
            "submitted job array {id} ({} tasks) and report job {rid} (afterany:{id})",
            a.tasks
        );
        eprintln!("watch:    {status}");
        eprintln!("          squeue -j {id},{rid}");
        eprintln!(
            "report:   {}/index.html once job {rid} has ended",
            s.out.display()
        );
        eprintln!("lost tasks (preemption, time limit, scancel)? run the same command again: only what is missing is computed");
        array_job = Some(id);
        report_job = Some(rid);
    } else {
        eprintln!("submit:   sbatch {}", s.array.display());
        eprintln!(
            "          sbatch --dependency=afterany:<array job id> {}",
            s.report.display()
        );
        eprintln!("          (or run this command again with --submit)");
    }
    let summary = serde_json::json!({
        "experiment": d.name,
        "tasks": a.tasks,
        "cache": cache.to_string_lossy(),
        "array_script": s.array.to_string_lossy(),
        "report_script": s.report.to_string_lossy(),
        "logs": s.logs.to_string_lossy(),
        "report": s.out.to_string_lossy(),
        "mem": s.mem,
        "max_shard_estimated_seconds": d.max_shard_seconds,
        "array_job": array_job,
        "report_job": report_job,
        "status_command": status,
    });
    let record = s.dir.join("submission.json");
    let _ = std::fs::write(
        &record,
        serde_json::to_vec_pretty(&summary).unwrap_or_default(),
    );
    println!("{summary}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(dir: &Path) -> SlurmArgs {
        SlurmArgs {
            experiment: dir.join("e.toml"),
            tasks: 4,
            cache: dir.join("cache dir"),
            partition: Some("batch".into()),
            time: Some("2:00:00".into()),
            constraint: Some("epyc7742".into()),
            account: None,
            mem: None,
            cpus_per_task: 2,
            dir: Some(dir.join("s")),
            out: Some(dir.join("rep")),
            sbatch_args: vec!["--qos=short".into()],
            submit: false,
            max_configs: 20_000,
        }
    }

    #[test]
    fn scripts_name_the_shards_the_cache_and_the_pins() {
        let t = tempfile::tempdir().unwrap();
        std::fs::write(t.path().join("e.toml"), "").unwrap();
        let d = Derived {
            name: "x".into(),
            peak_bytes: Some(3 << 30),
            max_shard_seconds: None,
        };
        let s = write_scripts(&args(t.path()), &d).unwrap();
        let a = std::fs::read_to_string(&s.array).unwrap();
        assert!(a.contains("#SBATCH --array=1-4\n"), "{a}");
        assert!(a.contains("--shard \"${SLURM_ARRAY_TASK_ID}/4\""), "{a}");
        assert!(
            a.contains("#SBATCH --partition=batch\n")
                && a.contains("#SBATCH --constraint=epyc7742\n")
        );
        assert!(a.contains("#SBATCH --time=2:00:00\n") && a.contains("#SBATCH --qos=short\n"));
        assert!(a.contains("#SBATCH --cpus-per-task=2\n"));
        // 3 GiB estimate -> 3840 + 256 MiB, and the shard may use exactly that.
        assert!(a.contains("#SBATCH --mem=4096M\n"), "{a}");
        assert!(
            a.contains(&format!("--max-memory {}", 4096u64 << 20)),
            "{a}"
        );
        // A path with a space is quoted for bash.
        assert!(a.contains("'"), "{a}");
        let r = std::fs::read_to_string(&s.report).unwrap();
        assert!(r.contains("--report-only") && !r.contains("--array"), "{r}");
        assert!(
            a.contains("--max-configs 20000") && r.contains("--max-configs 20000"),
            "{a}\n{r}"
        );
        assert!(s.logs.is_dir());
    }

    #[test]
    fn bad_values_are_input_errors() {
        let t = tempfile::tempdir().unwrap();
        let d = Derived {
            name: "x".into(),
            peak_bytes: None,
            max_shard_seconds: None,
        };
        let mut a = args(t.path());
        a.tasks = 0;
        assert_eq!(write_scripts(&a, &d).err().map(|e| e.exit_code()), Some(2));
        let mut a = args(t.path());
        a.mem = Some("lots".into());
        assert_eq!(write_scripts(&a, &d).err().map(|e| e.exit_code()), Some(2));
        assert_eq!(default_mem_mib(None), 4096);
        assert_eq!(default_mem_mib(Some(1 << 20)), 1024);
    }

    #[test]
    fn shell_quoting() {
        assert_eq!(sh("/a/b.toml"), "/a/b.toml");
        assert_eq!(sh("a b"), "'a b'");
        assert_eq!(sh("it's"), r"'it'\''s'");
    }
}
