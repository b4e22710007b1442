"""The Dockerfiles run exactly the Makefile targets that CI runs natively.

Docker cannot run here, so this test is what keeps the images honest: every RUN/CMD
step that installs or reproduces is a `make` target of the Makefile, `make test` (CI)
runs `venv` and the same `reproduce` recipe (with `--quick`), and `make -n` accepts
the targets with the variables the Dockerfiles pass. The wheel image must also have every
system library the native code of the wheels loads (`ldd` and `dpkg` on this machine).
"""

import importlib.metadata
import json
import os
import re
import shlex
import shutil
import site
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Debian release of the wheel image, pinned: `python:3.12-slim` follows Debian stable
WHEEL_IMAGE_SUITE = "bookworm"
DOCKERFILES = {
    "Dockerfile.dolfinx": "ghcr.io/fenics/dolfinx/dolfinx:v0.11.0",
    "Dockerfile.wheel": f"python:3.12-slim-{WHEEL_IMAGE_SUITE}",
}


def makefile_rules() -> dict[str, tuple[list[str], list[str]]]:
    """target -> (prerequisites, recipe lines)."""
    rules: dict[str, tuple[list[str], list[str]]] = {}
    current = None
    for line in (ROOT / "Makefile").read_text().splitlines():
        match = re.match(r"^([\w./$()-]+):(?!=)\s*(.*)$", line)
        if match and not line.startswith("\t"):
            current = match.group(1)
            rules[current] = (match.group(2).split(), [])
        elif line.startswith("\t") and current:
            rules[current][1].append(line.strip())
        elif not line.strip():
            current = None
    return rules


def make_invocations(dockerfile: Path) -> list[list[str]]:
    """The argument lists of every `make` call in RUN and CMD instructions."""
    calls = []
    for line in dockerfile.read_text().splitlines():
        if line.startswith("RUN ") and "make " in line and "apt-get" not in line:
            calls.append(shlex.split(line[4:]))
        elif line.startswith("CMD "):
            calls.append(json.loads(line[4:]))
    return [c for c in calls if c and c[0] == "make"]


@pytest.mark.parametrize("name", sorted(DOCKERFILES))
def test_dockerfile_uses_ci_make_targets(name):
    dockerfile = ROOT / "containers" / name
    text = dockerfile.read_text()
    assert f"FROM {DOCKERFILES[name]}" in text
    calls = make_invocations(dockerfile)
    targets = [c[1] for c in calls]
    assert targets == ["venv", "reproduce"], targets
    rules = makefile_rules()
    for call in calls:
        assert call[1] in rules
        variables = [a for a in call[2:] if "=" in a]
        dry = subprocess.run(
            ["make", "-n", "-C", str(ROOT), call[1], *variables, "VENV=/nonexistent-venv"],
            capture_output=True,
            text=True,
        )
        assert dry.returncode == 0, dry.stderr
        if call[1] == "venv":
            extras = dict(v.split("=", 1) for v in variables).get("EXTRAS")
            expected = f'-e ".[{extras}]"' if extras else '-e ".[fenics'
            assert expected in dry.stdout


def test_ci_runs_the_same_install_and_reproduce_recipes():
    rules = makefile_rules()
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^make test$", ci, re.M), ".ci/run must call the README's `make test`"
    assert "make test" in (ROOT / "README.md").read_text()
    assert "reproduce-quick" in rules["test"][0]
    assert "venv" in rules["test-serial"][0]
    (full,) = rules["reproduce"][1]
    (quick,) = rules["reproduce-quick"][1]
    assert quick == full.replace("reproduce all", "reproduce all --quick").replace(
        "$(OUT)", "$(OUT)_quick"
    )


# --- the wheel image has the system libraries the wheels' native code loads -----------------

# The binary packages of python:3.12-slim-bookworm (python:3.12.13-slim-bookworm, amd64), as
# listed in docker-library/repo-info, repos/python/local/3.12-slim-bookworm.md: the packages of
# debian:bookworm-slim (Priority: required, and apt) plus what the python image installs or
# keeps (ca-certificates, netbase, tzdata and the libraries its Python build links: libssl3,
# libsqlite3-0, libreadline8, libncursesw6, libgdbm6, ...). Not in it: libexpat1 (the image's
# Python bundles expat), libgomp1, and any X11, OpenGL, font or image library.
SLIM_BOOKWORM_PACKAGES = frozenset(
    """
    adduser apt base-files base-passwd bash bsdutils ca-certificates coreutils dash debconf
    debian-archive-keyring debianutils diffutils dpkg e2fsprogs findutils gcc-12-base gpgv
    grep gzip hostname init-system-helpers libacl1 libapt-pkg6.0 libattr1 libaudit-common
    libaudit1 libblkid1 libbz2-1.0 libc-bin libc6 libcap-ng0 libcap2 libcom-err2 libcrypt1
    libdb5.3 libdebconfclient0 libext2fs2 libffi8 libgcc-s1 libgcrypt20 libgdbm6 libgmp10
    libgnutls30 libgpg-error0 libgssapi-krb5-2 libhogweed6 libidn2-0 libk5crypto3
    libkeyutils1 libkrb5-3 libkrb5support0 liblz4-1 liblzma5 libmd0 libmount1 libncursesw6
    libnettle8 libnsl2 libp11-kit0 libpam-modules libpam-modules-bin libpam-runtime libpam0g
    libpcre2-8-0 libreadline8 libseccomp2 libselinux1 libsemanage-common libsemanage2
    libsepol2 libsmartcols1 libsqlite3-0 libss2 libssl3 libstdc++6 libsystemd0 libtasn1-6
    libtinfo6 libtirpc-common libtirpc3 libudev1 libunistring2 libuuid1 libxxhash0 libzstd1
    login logsave mawk mount ncurses-base ncurses-bin netbase openssl passwd perl-base
    readline-common sed sysvinit-utils tar tzdata usr-is-merged util-linux util-linux-extra
    zlib1g
    """.split()
)

# The wheels with native code that `make venv` installs. MPICH's UCX transports and libfabric
# providers (mpich/ucx/, mpich/libfabric/) are plugins it opens only when their system
# libraries (libibverbs, librdmacm, ...) exist, so they are left out.
NATIVE_WHEELS = ("gmsh", "vtk", "dolfinx-solver-real", "fenics-basix", "mpich")
OPTIONAL_PLUGIN_DIRS = {"ucx", "libfabric"}
# vtk links no system library: it opens libX11, libXcursor, libGL and libEGL itself (their
# sonames are strings in its libraries). libglvnd then opens the vendor library (Mesa's
# libEGL_mesa.so.0) and Mesa its driver (swrast_dri.so), which no file names: their packages.
VTK_RUNTIME_PACKAGES = ("libegl-mesa0", "libgl1-mesa-dri")
SONAME_STRING = re.compile(rb"lib[A-Za-z0-9_+-]+\.so\.[0-9]+")


def native_files(name: str) -> list[Path]:
    """The ELF files (libraries and extension modules) the distribution `name` installed."""
    dist = importlib.metadata.distribution(name)
    files = set()
    for entry in dist.files or []:
        if not re.search(r"\.so(\.\d+)*$", entry.name):
            continue
        if name == "mpich" and OPTIONAL_PLUGIN_DIRS & set(entry.parts[:-1]):
            continue
        path = Path(str(dist.locate_file(entry))).resolve()
        if path.is_file():
            with path.open("rb") as f:
                if f.read(4) == b"\x7fELF":
                    files.add(path)
    return sorted(files)


def ldd(files, library_path=()) -> tuple[set[tuple[str, str]], set[str]]:
    """The (soname, path) pairs ldd resolves for the files, and the sonames it cannot find."""
    env = dict(os.environ)
    paths = [*library_path, *env.get("LD_LIBRARY_PATH", "").split(os.pathsep)]
    env["LD_LIBRARY_PATH"] = os.pathsep.join(p for p in paths if p)
    out = subprocess.run(
        ["ldd", *map(str, files)], capture_output=True, text=True, env=env, check=False
    ).stdout
    resolved, missing = set(), set()
    for soname, target in re.findall(r"^\s*(\S+) => (\S+)", out, re.M):
        if target == "not":
            missing.add(soname)
        else:
            resolved.add((soname, target))
    return resolved, missing


def ldconfig_cache() -> dict[str, list[tuple[str, str]]]:
    """soname -> [(ABI tag, path)] of the dynamic linker's cache (what dlopen finds)."""
    ldconfig = shutil.which("ldconfig") or "/sbin/ldconfig"
    out = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, check=True).stdout
    cache: dict[str, list[tuple[str, str]]] = {}
    for soname, tag, path in re.findall(r"^\s*(\S+) \(([^)]*)\) => (\S+)$", out, re.M):
        cache.setdefault(soname, []).append((tag, path))
    return cache


def debian_packages(paths) -> dict[str, str]:
    """path -> the Debian package that installed it (`dpkg -S`, also under /usr-merge)."""
    candidates: dict[str, str] = {}
    for path in paths:
        for variant in (path, os.path.realpath(path)):
            candidates[variant] = path
            if variant.startswith("/usr/"):
                candidates[variant[4:]] = path
            else:
                candidates["/usr" + variant] = path
    out = subprocess.run(
        ["dpkg-query", "-S", *candidates], capture_output=True, text=True, check=False
    ).stdout
    owner = {}
    for line in out.splitlines():
        if line.startswith("diversion by") or ": " not in line:
            continue
        packages, path = line.split(": ", 1)
        if path in candidates:
            owner[candidates[path]] = packages.split(",")[0].split(":")[0].strip()
    return owner


def with_dependencies(packages) -> set[str]:
    """packages and everything apt-get installs with them (Pre-Depends and Depends)."""
    out = subprocess.run(
        ["dpkg-query", "-W", "-f", "${Package}\t${Provides}\t${Pre-Depends}, ${Depends}\n"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    depends: dict[str, set[str]] = {}
    providers: dict[str, set[str]] = {}
    for line in out.splitlines():
        name, provides, deps = line.split("\t")
        for clause in deps.split(","):
            if clause.strip():  # apt takes the first alternative that is not yet installed
                first = re.split(r"[\s(:|]", clause.strip(), maxsplit=1)[0]
                depends.setdefault(name, set()).add(first)
        for virtual in provides.split(","):
            if virtual.strip():
                providers.setdefault(re.split(r"[\s(:]", virtual.strip())[0], set()).add(name)
    done: set[str] = set()
    todo = list(packages)
    while todo:
        name = todo.pop()
        if name not in done:
            done.add(name)
            todo += depends.get(name, set()) | providers.get(name, set())
    return done


def apt_installed(dockerfile_text: str) -> set[str]:
    """The packages of the Dockerfile's `apt-get install` command."""
    text = dockerfile_text.replace("\\\n", " ")
    match = re.search(r"apt-get install ([^&;\n]*)", text)
    assert match, "no apt-get install in the Dockerfile"
    return {word for word in match.group(1).split() if not word.startswith("-")}


@pytest.mark.timeout(120)
def test_wheel_image_installs_the_system_libraries_of_the_wheels():
    if not (shutil.which("ldd") and shutil.which("dpkg-query")):
        pytest.skip("needs ldd and dpkg (a Debian machine)")
    os_release = Path("/etc/os-release")
    if f"VERSION_CODENAME={WHEEL_IMAGE_SUITE}" not in (
        os_release.read_text() if os_release.exists() else ""
    ):
        pytest.skip(
            f"package names come from this machine's dpkg: needs Debian {WHEEL_IMAGE_SUITE}"
        )
    files = {}
    for name in NATIVE_WHEELS:
        try:
            files[name] = native_files(name)
        except importlib.metadata.PackageNotFoundError:
            if name in ("gmsh", "vtk"):
                pytest.skip(f"{name} is not installed (`make venv` installs it)")
    wheel_files = {f for fs in files.values() for f in fs}
    # the wheels find each other's libraries through RPATHs or because Python loaded them first
    resolved, missing = ldd(sorted(wheel_files), sorted({str(f.parent) for f in wheel_files}))
    assert not missing, f"libraries the wheels link are not installed here: {sorted(missing)}"
    site_packages = [Path(p).resolve() for p in site.getsitepackages()]

    def from_wheels(path):
        real = Path(path).resolve()
        return real in wheel_files or any(real.is_relative_to(d) for d in site_packages)

    needed = {(soname, path) for soname, path in resolved if not from_wheels(path)}
    # the libraries vtk opens itself: sonames written in its files that no wheel ships
    opened = set()
    for f in files["vtk"]:
        opened |= {s.decode() for s in SONAME_STRING.findall(f.read_bytes())}
    opened -= {f.name for f in wheel_files} | {soname for soname, _ in resolved}
    cache = ldconfig_cache()
    libc = {path for soname, path in needed if soname == "libc.so.6"}
    abi = {tag for tag, path in cache.get("libc.so.6", []) if path in libc}
    for soname in sorted(opened):
        found = [path for tag, path in cache.get(soname, []) if tag in abi]
        if found:  # vtk skips the window systems it cannot open
            needed.add((soname, found[0]))
    more, missing = ldd(sorted({path for _, path in needed} - {path for _, path in resolved}))
    assert not missing, f"libraries vtk opens link libraries not installed here: {missing}"
    needed |= more

    owner = debian_packages(sorted({path for _, path in needed}))
    unowned = sorted(f"{soname} ({path})" for soname, path in needed if path not in owner)
    assert not unowned, f"system libraries that no Debian package installed: {unowned}"
    by_package: dict[str, set[str]] = {}
    for soname, path in needed:
        by_package.setdefault(owner[path], set()).add(soname)
    for package in VTK_RUNTIME_PACKAGES:
        by_package.setdefault(package, set()).add("(opened by libglvnd and Mesa)")

    dockerfile = (ROOT / "containers" / "Dockerfile.wheel").read_text()
    image = with_dependencies(apt_installed(dockerfile) | SLIM_BOOKWORM_PACKAGES)
    absent = {
        package: sorted(s) for package, s in sorted(by_package.items()) if package not in image
    }
    assert not absent, (
        "containers/Dockerfile.wheel must apt-get install these packages (package: the "
        f"system libraries of the wheels that it provides): {absent}"
    )
