//! A sweep as independent jobs for an existing scheduler: a Slurm job-array script (one array
//! task per point) and a plain one-command-per-line list (for GNU parallel, xargs, …). Each job
//! is `gscodec sweep … --lambdas λ --loss L --points-only`, which runs one point and writes its
//! `result.json` (or does nothing if that exists); `sweep --collect DIR` then builds the tables.

use std::path::{Path, PathBuf};

use super::{Plan, Point};

/// Quotes a word for a POSIX shell (single quotes unless it is plainly safe).
pub fn shell_quote(word: &str) -> String {
    let safe = !word.is_empty() && word.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if safe {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', r"'\''"))
    }
}

/// One shell command line per group of points that share their training
/// ([`Plan::training_groups`]): `exe sweep … --points-only --quiet`.
pub fn command_lines(exe: &Path, plan: &Plan, groups: &[Vec<Point>]) -> Vec<String> {
    groups
        .iter()
        .map(|g| {
            std::iter::once(exe.display().to_string()).chain(plan.group_command(g)).map(|w| shell_quote(&w)).collect::<Vec<_>>().join(" ")
        })
        .collect()
}

/// Path of the plain command list written beside the Slurm script `file`.
pub fn list_path(file: &Path) -> PathBuf {
    file.with_extension("commands.txt")
}

/// The plain list: one command per line (`parallel -j 4 < LIST`).
pub fn command_list(lines: &[String]) -> String {
    lines.iter().map(|l| format!("{l}\n")).collect()
}

/// A Slurm job-array script running task `i` = `lines[i]`; `collect` is the command that
/// merges the results afterwards (printed in the script's header).
pub fn slurm_script(lines: &[String], out: &Path, collect: &str) -> String {
    let log_dir = shell_quote(&out.join("points").display().to_string());
    let mut s = String::new();
    s.push_str("#!/bin/bash\n");
    s.push_str("# gscodec λ sweep as a Slurm job array, written by `gscodec sweep --emit-jobs`.\n");
    s.push_str("# Submit: sbatch THIS_FILE   (add --cpus-per-task / --time / --partition as your cluster needs)\n");
    s.push_str(&format!("# When every task has finished:\n#   {collect}\n"));
    s.push_str("#SBATCH --job-name=gscodec-sweep\n");
    s.push_str(&format!("#SBATCH --array=0-{}\n", lines.len().saturating_sub(1)));
    s.push_str(&format!("#SBATCH --output={}/slurm-%A_%a.log\n", out.join("points").display()));
    s.push_str("set -euo pipefail\n");
    s.push_str(&format!("mkdir -p {log_dir}\n"));
    s.push_str("case \"${SLURM_ARRAY_TASK_ID:?run this script with sbatch}\" in\n");
    for (i, l) in lines.iter().enumerate() {
        s.push_str(&format!("  {i}) {l} ;;\n"));
    }
    s.push_str("  *) echo \"no task $SLURM_ARRAY_TASK_ID\" >&2; exit 2 ;;\nesac\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quoting_is_shell_safe() {
        assert_eq!(shell_quote("/a/b-c_1.ply"), "/a/b-c_1.ply");
        assert_eq!(shell_quote("my scene"), "'my scene'");
        assert_eq!(shell_quote("it's"), r"'it'\''s'");
        assert_eq!(shell_quote(""), "''");
    }

    #[test]
    fn script_has_one_task_per_point() {
        let plan = Plan {
            input: "/d/lego 200".into(),
            out: "/o".into(),
            lambdas: vec![0.1, 0.01],
            losses: vec!["wdr".into()],
            iters: None,
            seeds: vec![0],
            retrain_iters: None,
            coding_breakdown: false,
            features: crate::loss::FeatureSpec::default(),
            wd_sigma: None,
            wd_warmup: None,
            search_distortion: crate::encoder::SearchDistortion::Mse,
            max_gaussians: None,
            init: None,
            backend: crate::encoder::Backend::Auto,
            dataset_args: Vec::new(),
        };
        let groups = plan.training_groups(&plan.points()).unwrap();
        let lines = command_lines(Path::new("/bin/gscodec"), &plan, &groups);
        assert_eq!(lines[1], "/bin/gscodec sweep '/d/lego 200' -o /o --lambdas 0.01 --loss wdr --points-only --quiet");
        let s = slurm_script(&lines, Path::new("/o"), "gscodec sweep X -o /o --collect /o");
        assert!(s.contains("#SBATCH --array=0-1\n"));
        assert!(s.contains("  1) /bin/gscodec sweep '/d/lego 200'"));
        assert_eq!(command_list(&lines).lines().count(), 2);
        assert_eq!(list_path(Path::new("/x/jobs.sh")), Path::new("/x/jobs.commands.txt"));
    }
}
