#!/usr/bin/env bash
# The installed package, as an engine team and an operator get it:
#   prefix       cmake --install into an empty prefix; the files, the exported
#                symbols, --version of every binary; a tiny engine (C99, C++11,
#                C++17, shared and static) built against the prefix alone, by
#                find_package and by pkg-config, filters a frame through the
#                installed daemon on the installed weights; the Python client
#                from the prefix does too.
#   client-only  -DHF_CLIENT_ONLY=ON configures with a C compiler only (no
#                C++, pkg-config, CUDA or image libraries probed), builds,
#                installs, and the C engine builds against it.
#   deb          cpack -G DEB: the package's control data and files, apt's
#                simulated install (apt-get install -s), then its contents
#                extracted and run (daemon, engine, --version).
#
#   install_test.sh MODE BUILD_DIR SOURCE_DIR WORK_DIR CC CXX "SANITIZE_FLAGS" PYTHON
#
# Every step prints what it does; the first failure ends the test (exit 1).
set -euo pipefail
mode=$1 build=$2 src=$3 work=$4 cc=$5 cxx=$6 san=$7 python=$8
version=$(sed -n 's/^#define HAIRFILTER_VERSION_STRING "\(.*\)"/\1/p' \
          "$build/include/hairfilter/hairfilter_version.h")
rm -rf "$work"
mkdir -p "$work"
daemon_pid=
cleanup() { [ -n "$daemon_pid" ] && kill "$daemon_pid" 2>/dev/null || true; }
trap cleanup EXIT
fail() { echo "install_test: $*" >&2; exit 1; }
step() { echo "== $*"; }

# find_package and pkg-config see only what is given to them here.
export CMAKE_PREFIX_PATH= PKG_CONFIG_PATH=
unset CPATH C_INCLUDE_PATH CPLUS_INCLUDE_PATH LIBRARY_PATH LD_LIBRARY_PATH || true
cflags="-Wall -Wextra -Werror -pedantic $san"

# Starts BIN on the Small weights of WEIGHTS_DIR, or with --config CONF
# (the installed example config: its weights folder, a free HTTP port);
# sets $url.
start_daemon() {
  local bin=$1 weights=$2 conf=${3:-} args
  rm -f "$work/d.sock" "$work/ready"
  if [ -n "$conf" ]; then
    args=(--config "$conf" --http tcp:127.0.0.1:0)
  else
    args=(--config none --weights "$weights/small.safetensors")
  fi
  "$bin" "${args[@]}" --listen "unix:$work/d.sock" --backend cpu-ref \
         --ready-file "$work/ready" > "$work/daemon.log" 2>&1 &
  daemon_pid=$!
  for _ in $(seq 1 1500); do
    [ -s "$work/ready" ] && break
    kill -0 "$daemon_pid" 2>/dev/null || { cat "$work/daemon.log"; fail "daemon did not start"; }
    sleep 0.02
  done
  [ -s "$work/ready" ] || fail "daemon not ready"
  url=$(head -n1 "$work/ready")
}

stop_daemon() {
  kill -TERM "$daemon_pid"
  wait "$daemon_pid" || fail "daemon exited with $?"
  daemon_pid=
}

# Runs each engine given on variant Small (VARIANT=...: another); all must
# print one and the same line.
run_engines() {
  local first= line variant=${VARIANT:-Small}
  for e in "$@"; do
    line=$("$e" "$url" "$variant") || fail "$e on $variant failed"
    echo "   $(basename "$e") $variant: $line"
    case $line in "library $version server $version result "*) ;; *) fail "$e: $line";; esac
    [ -z "$first" ] && first=$line
    [ "$line" = "$first" ] || fail "$e disagrees with the first engine"
  done
}

# Only hfc_* is exported or defined globally; no codec symbol is left undefined.
check_symbols() {
  local lib=$1 kind=$2 bad
  if [ "$kind" = shared ]; then
    bad=$(nm -D --defined-only "$lib" | awk '$2 ~ /^[TDBRVW]$/ {print $3}' | grep -v '^hfc_' || true)
  else
    bad=$(nm -g --defined-only "$lib" 2>/dev/null | awk 'NF == 3 {print $3}' | grep -v '^hfc_' |
          grep -v '^__odr_asan\|^__asan\|^__ubsan' || true)
  fi
  [ -z "$bad" ] || fail "$lib exports more than hfc_*: $bad"
  if nm -u "$lib" | grep -q ' hfp_'; then fail "$lib leaves hfp_* undefined"; fi
  nm -g --defined-only "$lib" | grep -q ' hfc_filter$' || fail "$lib has no hfc_filter"
}

# The engine project against PREFIX through find_package, then engine.c and
# engine.cpp through pkg-config; the binaries' paths in $engines.
build_engines() {
  local prefix=$1 tag=$2 cxx_too=$3
  step "$tag: engine by find_package(hairfilter CONFIG) from $prefix"
  local b="$work/engine-$tag"
  local langs=(-DCMAKE_CXX_COMPILER="$cxx")
  "${CMAKE:-cmake}" -S "$src/tests/install/engine" -B "$b" -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_C_COMPILER="$cc" "${langs[@]}" -DCMAKE_PREFIX_PATH="$prefix" \
      -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF -DCMAKE_FIND_USE_SYSTEM_PACKAGE_REGISTRY=OFF \
      -DCMAKE_C_FLAGS="$san" -DCMAKE_CXX_FLAGS="$san" -DCMAKE_EXPORT_COMPILE_COMMANDS=ON \
      > "$b.log" 2>&1 || { cat "$b.log"; fail "engine configure"; }
  grep -q "hairfilter $version from $prefix/" "$b.log" || { cat "$b.log"; fail "not the prefix's package"; }
  local targets=(engine_c engine_c_static)
  [ "$cxx_too" = yes ] && targets+=(engine_cpp11 engine_cpp17)
  "${CMAKE:-cmake}" --build "$b" --target "${targets[@]}" >> "$b.log" 2>&1 ||
      { cat "$b.log"; fail "engine build"; }
  # Nothing of the source or build tree is on the engine's command lines.
  if grep -q -e "-I$src" -e "-I$build" "$b/compile_commands.json"; then fail "engine saw the tree"; fi
  engines=()
  for t in "${targets[@]}"; do engines+=("$b/$t"); done

  # OpenSSL's development files absent (libssl-dev not installed): only the
  # static library needs them, so find_package still gives the shared one
  # (it failed as a whole, OpenSSL being a required dependency).
  step "$tag: engine by find_package without OpenSSL's development files"
  local bn="$work/engine-$tag-nossl"
  "${CMAKE:-cmake}" -S "$src/tests/install/engine" -B "$bn" -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_C_COMPILER="$cc" "${langs[@]}" -DCMAKE_PREFIX_PATH="$prefix" \
      -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF -DCMAKE_FIND_USE_SYSTEM_PACKAGE_REGISTRY=OFF \
      -DCMAKE_DISABLE_FIND_PACKAGE_OpenSSL=TRUE -DENGINE_SHARED_ONLY=ON \
      -DCMAKE_C_FLAGS="$san" -DCMAKE_CXX_FLAGS="$san" > "$bn.log" 2>&1 ||
      { cat "$bn.log"; fail "engine configure without OpenSSL's development files"; }
  grep -q "hairfilter::client_static needs them" "$bn.log" ||
      { cat "$bn.log"; fail "no word on what lacking OpenSSL costs"; }
  "${CMAKE:-cmake}" --build "$bn" --target engine_c >> "$bn.log" 2>&1 ||
      { cat "$bn.log"; fail "engine build without OpenSSL's development files"; }
  engines+=("$bn/engine_c")

  step "$tag: engine by pkg-config from $prefix"
  local pcdir
  pcdir=$(dirname "$(find "$prefix" -name hairfilter.pc | head -n1)")
  local pc=(env PKG_CONFIG_LIBDIR="$pcdir" PKG_CONFIG_PATH= pkg-config)
  [ "$("${pc[@]}" --modversion hairfilter)" = "$version" ] || fail "pkg-config version"
  local libdir
  libdir=$("${pc[@]}" --variable=libdir hairfilter)
  # shellcheck disable=SC2046
  "$cc" -std=c99 $cflags -I"$src/tests/install/engine" "$src/tests/install/engine/engine.c" \
      $("${pc[@]}" --cflags --libs hairfilter) -Wl,-rpath,"$libdir" -o "$work/pc_c_$tag" ||
      fail "pkg-config C build"
  engines+=("$work/pc_c_$tag")
  # The static library by its path, as client/lib/README.md says: no
  # libhairfilter.so in the program, which starts without an rpath.
  # shellcheck disable=SC2046
  "$cc" -std=c99 $cflags -I"$src/tests/install/engine" "$src/tests/install/engine/engine.c" \
      $("${pc[@]}" --cflags hairfilter) "$libdir/libhairfilter.a" -lssl -lcrypto \
      -o "$work/pc_static_c_$tag" || fail "pkg-config static C build"
  if ldd "$work/pc_static_c_$tag" | grep -q libhairfilter; then
    fail "pkg-config static C build links libhairfilter.so"
  fi
  engines+=("$work/pc_static_c_$tag")
  if [ "$cxx_too" = yes ]; then
    # shellcheck disable=SC2046
    "$cxx" -std=c++11 $cflags -I"$src/tests/install/engine" \
        "$src/tests/install/engine/engine.cpp" $("${pc[@]}" --cflags --libs hairfilter) \
        -Wl,-rpath,"$libdir" -o "$work/pc_cpp_$tag" || fail "pkg-config C++ build"
    engines+=("$work/pc_cpp_$tag")
  fi
}

case $mode in
prefix)
  prefix=$work/prefix
  step "cmake --install $build --prefix $prefix"
  "${CMAKE:-cmake}" --install "$build" --prefix "$prefix" > "$work/install.log" ||
      fail "install"
  libdir=$(dirname "$(find "$prefix" -name libhairfilter.a | head -n1)")
  for f in bin/hairfilter bin/hairfilterd bin/hairfilter-load \
           include/hairfilter/hairfilter.h include/hairfilter/hairfilter.hpp \
           include/hairfilter/hairfilter_version.h \
           share/hairfilter/weights/base.safetensors share/hairfilter/weights/base.md \
           share/hairfilter/weights/hfnet.py share/hairfilter/bench/bench_torch.py \
           share/doc/hairfilter/LICENSE share/doc/hairfilter/CHANGELOG.md \
           lib/systemd/system/hairfilterd.service share/hairfilter/hairfilterd.conf \
           share/doc/hairfilter/SERVER.md share/doc/hairfilter/CLIENT.md \
           share/doc/hairfilter/PROTOCOL.md share/doc/hairfilter/FEATURES.md \
           lib/python3/dist-packages/hairfilter/__init__.py \
           lib/python3/dist-packages/hairfilter/_version.py; do
    [ -e "$prefix/$f" ] || fail "missing $f"
  done
  for f in libhairfilter.so libhairfilter.a pkgconfig/hairfilter.pc \
           cmake/hairfilter/hairfilterConfig.cmake cmake/hairfilter/hairfilterConfigVersion.cmake \
           cmake/hairfilter/hairfilterTargets.cmake; do
    [ -e "$libdir/$f" ] || fail "missing $libdir/$f"
  done
  soname=$(readelf -d "$libdir/libhairfilter.so" | sed -n 's/.*SONAME.*\[\(.*\)\]/\1/p')
  echo "   SONAME $soname"
  case $version in 0.*) want=libhairfilter.so.${version%.*};; *) want=libhairfilter.so.${version%%.*};; esac
  [ "$soname" = "$want" ] || fail "SONAME $soname, want $want"
  [ -e "$libdir/$soname" ] || fail "no $soname"
  check_symbols "$libdir/libhairfilter.so" shared
  check_symbols "$libdir/libhairfilter.a" static
  grep -q "^ExecStart=$prefix/bin/hairfilterd --config /etc/hairfilter/hairfilterd.conf$" \
      "$prefix/lib/systemd/system/hairfilterd.service" ||
      fail "the unit does not start $prefix/bin/hairfilterd"
  grep -q "^weights-dir = $prefix/share/hairfilter/weights$" \
      "$prefix/share/hairfilter/hairfilterd.conf" || fail "the config's weights"
  step "--version"
  for b in hairfilter hairfilterd hairfilter-load; do
    out=$("$prefix/bin/$b" --version) || fail "$b --version"
    echo "   $out"
    case $out in "$b $version "*) ;; *) fail "$b --version: $out";; esac
  done
  # The daemon answers --version whatever state its config file is in.
  echo "no such key = 1" > "$work/broken.conf"
  if "$prefix/bin/hairfilterd" --config "$work/broken.conf" > /dev/null 2>&1; then
    fail "hairfilterd took a broken config file"
  fi
  "$prefix/bin/hairfilterd" --config "$work/broken.conf" --version | grep -q "^hairfilterd $version " ||
      fail "hairfilterd --version with a broken config file"

  build_engines "$prefix" prefix yes
  step "engines through the installed daemon, on the installed config"
  start_daemon "$prefix/bin/hairfilterd" "" "$prefix/share/hairfilter/hairfilterd.conf"
  run_engines "${engines[@]}"
  step "the C++ engines on KernelAC, the estimate in a buffer of its own (set_estimate)"
  cpp=()
  for e in "${engines[@]}"; do case $(basename "$e") in *cpp*) cpp+=("$e");; esac; done
  [ ${#cpp[@]} -gt 0 ] || fail "no C++ engine was built"
  VARIANT=KernelAC run_engines "${cpp[@]}"
  step "the installed example filter_exr.cpp, built as its comment says, on a feature EXR"
  ex="$prefix/share/doc/hairfilter/examples/filter_exr.cpp"
  [ -f "$ex" ] || fail "no $ex"
  # The comment's command, word for word, with PKG_CONFIG_PATH naming the prefix.
  cmd=$(sed -n 's|^//[[:space:]]*\(c++ -std.*\)|\1|p' "$ex")
  [ -n "$cmd" ] || fail "no build command in $ex"
  pcdir=$(dirname "$(find "$prefix" -name hairfilter.pc | head -n1)")
  (cd "$(dirname "$ex")" &&
      PKG_CONFIG_PATH="$pcdir" bash -c "${cmd/c++ /$cxx $san } -o '$work/filter_exr'") ||
      fail "the example does not build with: $cmd"
  "$work/filter_exr" "$url" "$src/tests/data/field/frame-64x64.exr" "$work/ex.exr" ||
      fail "the example failed"
  if "$python" -c 'import numpy' 2>/dev/null; then
    step "the installed Python client"
    PYTHONPATH="$prefix/lib/python3/dist-packages" "$python" - "$url" "$version" <<'EOF'
import sys, numpy as np, hairfilter
url, version = sys.argv[1:]
assert hairfilter.__version__ == version, hairfilter.__version__
with hairfilter.Client(url) as hf:
    assert hf.info.software_version == version
    done = hf.filter("Small", np.zeros((24, 32, 24), np.float32))
    assert done.result.shape == (24, 32, 3)
print("   python client", hairfilter.__version__, "ok")
EOF
  fi
  stop_daemon
  ;;

client-only)
  step "configure -DHF_CLIENT_ONLY=ON with only a C compiler"
  b=$work/build
  "${CMAKE:-cmake}" -S "$src" -B "$b" -DHF_CLIENT_ONLY=ON -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_C_COMPILER="$cc" -DCMAKE_C_FLAGS="$san" -DPKG_CONFIG_EXECUTABLE=/nonexistent \
      > "$work/configure.log" 2>&1 || { cat "$work/configure.log"; fail "configure"; }
  for v in CMAKE_CXX_COMPILER: CMAKE_CUDA_COMPILER OPENEXR CJSON LIBUV OSMESA CUDAToolkit_ pkgcfg_lib; do
    if grep -q "^$v" "$b/CMakeCache.txt"; then fail "client-only configure looked for $v"; fi
  done
  "${CMAKE:-cmake}" --build "$b" -j2 > "$work/build.log" 2>&1 || { cat "$work/build.log"; fail "build"; }
  "${CMAKE:-cmake}" --install "$b" --prefix "$work/prefix" > "$work/install.log" || fail "install"
  [ ! -e "$work/prefix/bin/hairfilterd" ] || fail "client-only installed the daemon"
  "$work/prefix/bin/hairfilter-load" --version | grep -q "hairfilter-load $version" ||
      fail "hairfilter-load --version"
  check_symbols "$(find "$work/prefix" -name libhairfilter.so | head -n1)" shared
  build_engines "$work/prefix" client-only no
  step "engines through the tree's daemon"
  start_daemon "$build/hairfilterd" "$src/weights"
  run_engines "${engines[@]}"
  stop_daemon
  ;;

deb)
  step "cpack -G DEB"
  (cd "$work" && "${CPACK:-cpack}" --config "$build/CPackConfig.cmake" -G DEB -B "$work/pkg" \
     > "$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; fail "cpack"; }
  deb=$(ls "$work"/pkg/hairfilter_"$version"_*.deb)
  echo "   $deb ($(du -h "$deb" | cut -f1))"
  dpkg-deb -I "$deb" > "$work/info.txt"
  sed 's/^/   /' "$work/info.txt"
  grep -q "^ Package: hairfilter$" "$work/info.txt" || fail "package name"
  grep -q "^ Version: $version$" "$work/info.txt" || fail "package version"
  grep -q "^ Depends:.*libuv1" "$work/info.txt" || fail "no libuv1 among the dependencies"
  for s in postinst prerm postrm shlibs triggers; do
    grep -E ' bytes, +[0-9]+ lines' "$work/info.txt" | grep -qw "$s" ||
        fail "no $s in the control data"
  done
  dpkg-deb -c "$deb" > "$work/contents.txt"
  for f in ./usr/bin/hairfilterd ./usr/bin/hairfilter ./usr/bin/hairfilter-load \
           ./usr/include/hairfilter/hairfilter.h ./usr/share/hairfilter/weights/base.safetensors \
           ./usr/lib/systemd/system/hairfilterd.service ./usr/share/doc/hairfilter/copyright \
           ./usr/share/hairfilter/hairfilterd.conf \
           ./usr/lib/python3/dist-packages/hairfilter/client.py; do
    grep -q " $f$" "$work/contents.txt" || fail "the DEB lacks $f"
  done
  grep -q "libhairfilter.so.0" "$work/contents.txt" || fail "the DEB lacks the shared library"
  for s in postinst prerm postrm; do
    dpkg-deb --ctrl-tarfile "$deb" | tar -xO "./$s" | sh -n || fail "$s is not valid sh"
  done
  # apt's own check that `apt install ./hairfilter_*.deb` would go through on
  # this machine (every dependency found), changing nothing (-s).
  if command -v apt-get >/dev/null; then
    step "apt-get install -s $deb"
    apt-get install -s "$deb" > "$work/apt.txt" 2>&1 || { cat "$work/apt.txt"; fail "apt-get -s"; }
    grep -q "^Inst hairfilter (${version//./\\.} " "$work/apt.txt" ||
        { cat "$work/apt.txt"; fail "apt would not install the package"; }
    grep "^Inst " "$work/apt.txt" | sed 's/^/   /'
  fi
  step "the DEB's files, extracted and run"
  root=$work/root
  dpkg-deb -x "$deb" "$root"
  grep -q "^ExecStart=/usr/bin/hairfilterd" "$root/usr/lib/systemd/system/hairfilterd.service" ||
      fail "the unit does not start /usr/bin/hairfilterd"
  grep -q "^weights-dir = /usr/share/hairfilter/weights$" \
      "$root/usr/share/hairfilter/hairfilterd.conf" || fail "the config's weights"
  dpkg-deb -e "$deb" "$work/control"
  grep -q "/usr/share/hairfilter/hairfilterd.conf" "$work/control/postinst" ||
      fail "the postinst does not put the config in /etc/hairfilter"
  for b in hairfilter hairfilterd hairfilter-load; do
    "$root/usr/bin/$b" --version | grep -q "^$b $version" || fail "$b --version"
  done
  # The .pc file is relative to itself, so the extracted tree builds too.
  pcdir=$(dirname "$(find "$root" -name hairfilter.pc | head -n1)")
  # shellcheck disable=SC2046
  "$cc" -std=c99 $cflags -I"$src/tests/install/engine" "$src/tests/install/engine/engine.c" \
      $(env PKG_CONFIG_LIBDIR="$pcdir" pkg-config --cflags --libs hairfilter) \
      -Wl,-rpath,"$(env PKG_CONFIG_LIBDIR="$pcdir" pkg-config --variable=libdir hairfilter)" \
      -o "$work/engine_deb" || fail "engine against the DEB's files"
  start_daemon "$root/usr/bin/hairfilterd" "$root/usr/share/hairfilter/weights"
  run_engines "$work/engine_deb"
  stop_daemon
  ;;
*)
  fail "mode $mode"
  ;;
esac
echo "install_test $mode: ok"
