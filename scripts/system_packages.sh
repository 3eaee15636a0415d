#!/usr/bin/env bash
# System packages that some tests need, from the distribution (Debian/Ubuntu, apt):
#   browser  chromium: the HTML report opened in a headless browser (tests/test_report_browser.py)
#   slurm    slurmctld slurmd slurm-client slurmdbd munge mariadb-server: a one-node SLURM cluster with
#            job accounting (tests/test_slurm.py, `make slurm-test`)
# Installs only what is missing and starts no service: the tests run their daemons themselves.
# Without root, sudo or apt it says what to install and exits 0 (the tests that need it then skip,
# outside CI).
set -euo pipefail

declare -A PACKAGES=(
  [browser]="chromium"
  [slurm]="slurmctld slurmd slurm-client slurmdbd munge mariadb-server"
)
declare -A PROBES=(
  [browser]="chromium"
  [slurm]="slurmctld slurmd sbatch srun sacct slurmdbd munged mariadbd"
)

want=()
for group in "$@"; do
  [ -n "${PACKAGES[$group]:-}" ] || { echo "system_packages: unknown group '$group' (browser, slurm)" >&2; exit 2; }
  for probe in ${PROBES[$group]}; do
    if ! PATH="$PATH:/usr/sbin:/sbin" command -v "$probe" >/dev/null; then
      want+=(${PACKAGES[$group]})
      break
    fi
  done
done
[ ${#want[@]} -gt 0 ] || exit 0

SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null && sudo -n true 2>/dev/null && SUDO="sudo -n"
if ! command -v apt-get >/dev/null || { [ "$(id -u)" -ne 0 ] && [ -z "$SUDO" ]; }; then
  echo "system_packages: install ${want[*]} (Debian/Ubuntu package names) to run the tests that need them" >&2
  exit 0
fi

# No service starts during the install (policy-rc.d 101 = action forbidden), unless a policy exists.
policy=/usr/sbin/policy-rc.d
made_policy=""
if [ ! -e "$policy" ]; then
  printf '#!/bin/sh\nexit 101\n' | $SUDO tee "$policy" >/dev/null
  $SUDO chmod 755 "$policy"
  made_policy=1
fi
cleanup() { [ -z "$made_policy" ] || $SUDO rm -f "$policy"; }
trap cleanup EXIT

echo "system_packages: installing ${want[*]}"
log=$(mktemp)
if ! { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
  --no-install-recommends "${want[@]}"; } >"$log" 2>&1; then
  echo "system_packages: apt-get could not install ${want[*]}:" >&2
  tail -n 20 "$log" >&2
  rm -f "$log"
  exit 1
fi
rm -f "$log"
