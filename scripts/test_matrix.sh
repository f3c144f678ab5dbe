#!/usr/bin/env bash
# The suite the ways a user's machine can differ (docs/DESIGN.md, "Determinism"): each configuration runs the
# README's test suite (ruff + pytest) once, in this clone, and prints its time; the last line sums them up.
#
#   bash scripts/test_matrix.sh                 # every configuration below (about 10 min each on 2 cores)
#   bash scripts/test_matrix.sh coretype-set shuffled
#   bash scripts/test_matrix.sh pairwise        # two runs that cover every value of every dimension
#
# configurations:
#   ci              as .ci/run (the machine's own environment)
#   coretype-set    OPENBLAS_CORETYPE=Haswell OPENBLAS_L2_SIZE=512 (as machines set them for older OpenBLAS builds)
#   coretype-unset  neither variable set
#   threads-1       one BLAS / OpenMP / onnxruntime thread (PRT_ORT_THREADS caps every session)
#   threads-2       two of each
#   shuffled        test order shuffled by pytest-randomly (seed printed; PRT_TEST_SEED=N repeats one)
#   twice           the suite twice in a row in the same clone: the second run must pass and the clone stay clean
#   mixed           coretype-set + threads-1 + shuffled, in one run
#   pairwise        = mixed, then coretype-unset + threads-2 + twice
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh >/dev/null || { echo "test_matrix: setup failed"; exit 1; }

ALL=(ci coretype-set coretype-unset threads-1 threads-2 shuffled twice)
configs=("$@")
[ ${#configs[@]} -eq 0 ] && configs=("${ALL[@]}")
declare -a summary
failed=0

run_suite() {  # NAME ENV... -- PYTEST_ARGS...
    local name=$1; shift
    local envs=() args=()
    while [ $# -gt 0 ] && [ "$1" != "--" ]; do envs+=("$1"); shift; done
    [ $# -gt 0 ] && shift
    args=("$@")
    local t0=$SECONDS
    echo "== $name: ${envs[*]:-(machine environment)} pytest ${args[*]:-}"
    if env "${envs[@]}" python3 -m ruff check prt_torch train export tests \
        && env "${envs[@]}" python3 -m pytest -q -p no:cacheprovider "${args[@]}" tests; then
        summary+=("$name: passed in $((SECONDS - t0)) s")
    else
        summary+=("$name: FAILED after $((SECONDS - t0)) s")
        failed=1
    fi
}

seed=${PRT_TEST_SEED:-$RANDOM}
unset_coretype=(-u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE)
set_coretype=(OPENBLAS_CORETYPE=Haswell OPENBLAS_L2_SIZE=512)
one=(OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 PRT_ORT_THREADS=1)
two=(OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=2 MKL_NUM_THREADS=2 PRT_ORT_THREADS=2)

twice() {  # ENV...: the suite twice; nothing the first run leaves may change the second or the clone
    local before after
    before=$(git status --porcelain)
    run_suite "twice (1/2)" "$@" -- -p no:randomly
    run_suite "twice (2/2)" "$@" -- -p no:randomly
    after=$(git status --porcelain)
    if [ "$before" != "$after" ]; then
        summary+=("twice: the clone changed: $(diff <(echo "$before") <(echo "$after") | tr '\n' ' ')")
        failed=1
    fi
}

mixed() {
    run_suite "coretype-set + threads-1 + shuffled (seed $seed)" "${set_coretype[@]}" "${one[@]}" -- \
        "--randomly-seed=$seed"
}

for c in "${configs[@]}"; do
    case $c in
        ci) run_suite ci -- -p no:randomly ;;
        coretype-set) run_suite coretype-set "${set_coretype[@]}" -- -p no:randomly ;;
        coretype-unset) run_suite coretype-unset "${unset_coretype[@]}" -- -p no:randomly ;;
        threads-1) run_suite threads-1 "${one[@]}" -- -p no:randomly ;;
        threads-2) run_suite threads-2 "${two[@]}" -- -p no:randomly ;;
        shuffled) run_suite "shuffled (seed $seed)" -- "--randomly-seed=$seed" ;;
        twice) twice ;;
        mixed) mixed ;;
        pairwise) mixed; twice "${unset_coretype[@]}" "${two[@]}" ;;
        *) echo "test_matrix: unknown configuration '$c' (expected: ${ALL[*]} mixed pairwise)"; exit 2 ;;
    esac
done
printf '%s\n' "${summary[@]}"
exit $failed
