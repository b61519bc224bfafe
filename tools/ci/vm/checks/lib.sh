# Shared by the guest checks (sourced): PASS/FAIL lines, a summary, TPL2 through tcs-client.
#   check NAME STATUS DETAIL...   STATUS 0 = PASS; prints "CHECK NAME: PASS|FAIL DETAIL"
#   summary                       prints every result again; exit status 1 when one failed
results=()
check() {
  local name=$1 ok=$2; shift 2
  results+=("CHECK $name: $([ "$ok" = 0 ] && echo PASS || echo FAIL) $*")
  echo "${results[-1]}"
}
# (the status is the word after the check's name: a detail may itself say "FAILED")
summary() {
  echo; echo "=== $1: $(printf '%s\n' "${results[@]}" | grep -c '^CHECK [^ ]*: PASS') passed, $(printf '%s\n' "${results[@]}" | grep -c '^CHECK [^ ]*: FAIL') failed"
  printf '%s\n' "${results[@]}"
  ! printf '%s\n' "${results[@]}" | grep -q '^CHECK [^ ]*: FAIL'
}
step() { echo; echo "=== $* (guest up $(cut -d' ' -f1 /proc/uptime) s)"; }
since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }
pwfile=$(mktemp); echo admin > "$pwfile"
: "${TCS_CLIENT:=tcs-client}"
client() { timeout "${CLIENT_TIMEOUT:-300}" "$TCS_CLIENT" --user admin --password-file "$pwfile" --port "${TPL2_PORT:-65432}" "$@"; }
value() { client get -v "$1" 2>/dev/null; }
# wait_for SECONDS COMMAND...: until COMMAND succeeds (1 s apart)
wait_for() {
  local end=$(( $(date +%s) + $1 )); shift
  until "$@"; do [ "$(date +%s)" -lt "$end" ] || return 1; sleep 1; done
}
# how much slower than real hardware the clock of the checks runs (hwfile.py --slowdown):
# measured in this guest (slowdown.py: ~0.75 x how much slower it interprets; at least 5 under
# software emulation, TCG, at least 1 with KVM); TCS_VM_SLOWDOWN overrides
SLOWDOWN=${TCS_VM_SLOWDOWN:-$(python "$(dirname "${BASH_SOURCE[0]}")/slowdown.py" --floor "$([ "${TCS_VM_ACCEL:-tcg}" = kvm ] && echo 1 || echo 5)")}
# hwfile [--channel CH] > FILE: the simulated telescope's hardware file for the checks
hwfile() { python "$(dirname "${BASH_SOURCE[0]}")/hwfile.py" hwconfig/sim.toml --slowdown "$SLOWDOWN" "$@"; }
