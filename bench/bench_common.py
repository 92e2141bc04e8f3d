"""Shared by the bench scripts: running a command under /usr/bin/time."""
import os, re, subprocess

# The evaluation scripts need numpy, which the README's setup installs for Debian's Python
# (python3-numpy); another python3 first on PATH (pyenv) may not have it.
PYTHON = "/usr/bin/python3"


def timed(cmd, timeout=None, check=False):
    """Runs `cmd`; returns (CompletedProcess, seconds, peak RSS MB), or (None, None, None) when it
    ran past `timeout` (it is then stopped). With `check`, a failure ends the script with its output."""
    try:
        r = subprocess.run(["/usr/bin/time", "-f", "TIME %e %M"] + cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        subprocess.run(["pkill", "-f", os.path.basename(cmd[0])])  # /usr/bin/time leaves its child running
        return None, None, None
    if check and r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    t, m = re.search(r"TIME ([\d.]+) (\d+)", r.stderr).groups()
    return r, float(t), int(m) / 1024


def write_report(lines, path):
    """Prints the report (lines joined) and writes it to `path`."""
    report = "\n".join(lines)
    print(report)
    open(path, "w").write(report + "\n")
