# Sourced by bench/mpi_speedup.sh and bench/mpi_rank_cpu.sh (run from the repository root): the
# three MPI workloads, so that both scripts time the same commands.
# args_of WORKLOAD: the arguments after `opal`; OUT stands for the output directory.
LS=crates/opal-inverse/tests/data/lights_small
args_of() {
  case "$1" in
    render) echo "render crates/opal/tests/data/cbox/scene.xml -o OUT/o.exr --spp 1024 --threads 1 --quiet" ;;
    gonio) echo "gonio simulate -o OUT/curves.csv --photons 40000000 --ndf ggx:0.15 --entry rough --threads 1 --quiet" ;;
    delight) echo "delight --scene $LS/scene.xml --views $LS/transforms.json -o OUT/d --light-paths 2000000 --iterations 3 --threads 1 --quiet" ;;
  esac
}
