#!/usr/bin/env python3
"""Checks the Dockerfile without a Docker engine, as faithfully as a root shell allows.

1. Context: copies the repository the way `docker build` sends it (Docker's .dockerignore
   rules: last matching pattern wins, `!` re-includes, a matched folder drops its contents).
2. Builder stage: runs its RUN commands verbatim in that copy with the host's Rust toolchain,
   a fresh CARGO_HOME (crates are downloaded, as in the image) and no target/ (a full release
   build: minutes). A private mount namespace puts an empty folder over /usr/local/bin so the
   builder's `cp ... /usr/local/bin/` lands there.
3. Runtime stages: `debootstrap --variant=minbase bookworm` (the package set of
   debian:bookworm-slim), then each stage's RUN in a chroot, its COPY --from=builder, its ENV
   and USER; `ldd` of every binary copied in.
4. Runs the images in a private network namespace (only loopback, like a container) with
   /proc, /sys and /dev mounted, as the stage's user (chroot --userspec), with the stage's
   ENV and ENTRYPOINT plus the `docker run` arguments docs/OPERATIONS.md shows:
   - the service with only the image's ENV must refuse to start (no submit token);
   - `-e TESSERA_OPEN_SUBMIT=true`: a farm with local workers renders examples/thesis.ray,
     and the PNG is valid and byte-identical to `tessera-render` run in the worker image;
   - tokens, no local workers, and a `tessera-worker --server ... --token ...` from the
     worker image: it claims every tile; the first job survived the restart in /data.

Needs root, Linux (unshare, chroot, mount), debootstrap (`apt-get install debootstrap`), a
reachable Debian mirror and crates.io. Run as `nice -n 15 scripts/docker-emulate.py`.
Not emulated: the images' own rust:1-bookworm toolchain (the host's is used; both build for
bookworm's glibc), layer caching, and Docker's port publishing.
"""

import argparse
import json
import os
import re
import shlex
import shutil
import signal
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
BUILDER_BIN = "/usr/local/bin"

passed = 0
failed = 0


def log(msg):
    print(f"== {msg}", flush=True)


def check(ok, what):
    global passed, failed
    if ok:
        passed += 1
        print(f"ok   {what}", flush=True)
    else:
        failed += 1
        print(f"FAIL {what}", flush=True)
    return ok


def run(cmd, **kw):
    print("$ " + " ".join(cmd), flush=True)
    return subprocess.run(cmd, check=True, **kw)


# ---------------------------------------------------------------- Dockerfile and context


def parse_dockerfile(path):
    """Stages as dicts: name, base, instrs [(OP, rest)]. Comment lines are dropped even inside
    continuations, as Docker does."""
    stages, logical, cur = [], [], ""
    with open(path) as f:
        for raw in f:
            line = raw.rstrip("\n")
            if line.strip().startswith("#"):
                continue
            if line.rstrip().endswith("\\"):
                cur += line.rstrip()[:-1] + " "
                continue
            cur += line
            if cur.strip():
                logical.append(cur.strip())
            cur = ""
    for line in logical:
        op, _, rest = line.partition(" ")
        op, rest = op.upper(), rest.strip()
        if op == "FROM":
            words = rest.split()
            name = words[2] if len(words) == 3 and words[1].upper() == "AS" else None
            stages.append({"name": name, "base": words[0], "instrs": []})
        elif op in ("WORKDIR", "COPY", "RUN", "ENV", "USER", "VOLUME", "EXPOSE", "ENTRYPOINT"):
            stages[-1]["instrs"].append((op, rest))
        else:
            sys.exit(f"docker-emulate: instruction {op} is not emulated; teach the script")
    return stages


def parse_env(rest):
    words = shlex.split(rest)
    if words and "=" not in words[0]:  # legacy `ENV KEY value`
        return {words[0]: rest.split(None, 1)[1]}
    return dict(w.split("=", 1) for w in words)


def dockerignore_rules(path):
    rules = []
    if not os.path.exists(path):
        return rules
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            negate = line.startswith("!")
            pat = os.path.normpath(line[1:] if negate else line).lstrip("/")
            rules.append((negate, re.compile("^" + glob_to_regex(pat) + "$"), line))
    return rules


def glob_to_regex(pat):
    """Go's filepath.Match plus `**` (any number of folders), as Docker's patternmatcher."""
    out, i = "", 0
    while i < len(pat):
        c = pat[i]
        if pat.startswith("**/", i):
            out += "(.*/)?"
            i += 3
            continue
        if pat.startswith("**", i):
            out += ".*"
            i += 2
            continue
        if c == "*":
            out += "[^/]*"
        elif c == "?":
            out += "[^/]"
        elif c == "[":
            j = pat.index("]", i)
            cls = pat[i + 1 : j]
            out += "[" + ("^" + cls[1:] if cls.startswith("^") else cls) + "]"
            i = j
        elif c == "\\" and i + 1 < len(pat):
            out += re.escape(pat[i + 1])
            i += 1
        else:
            out += re.escape(c)
        i += 1
    return out


def ignored(rel, rules):
    """A path is excluded when the last rule matching it or one of its parent folders is not
    a `!` rule."""
    parts = rel.split("/")
    prefixes = ["/".join(parts[: k + 1]) for k in range(len(parts))]
    verdict = False
    for negate, rx, _ in rules:
        if any(rx.match(p) for p in prefixes):
            verdict = not negate
    return verdict


def assemble_context(ctx):
    rules = dockerignore_rules(os.path.join(ROOT, ".dockerignore"))
    check(bool(rules), ".dockerignore exists (without it COPY . . sends target/ and .git)")
    if os.path.exists(ctx):
        shutil.rmtree(ctx)
    sent = total = nsent = 0
    for dirpath, dirnames, filenames in os.walk(ROOT):
        for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            src = os.path.join(dirpath, name)
            rel = os.path.relpath(src, ROOT)
            size = os.lstat(src).st_size
            total += size
            if ignored(rel, rules):
                continue
            dst = os.path.join(ctx, rel)
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            if os.path.islink(src):
                os.symlink(os.readlink(src), dst)
            else:
                shutil.copy2(src, dst)
            sent += size
            nsent += 1
    log(f"context: {nsent} files, {sent / 1e6:.1f} MB sent of {total / 1e6:.1f} MB in the tree")
    check(not os.path.exists(os.path.join(ctx, "target")), "context holds no target/")
    check(sent < 50e6, "context under 50 MB")
    return ctx


# ---------------------------------------------------------------- builder stage


def build(stage, ctx, work, nice):
    base = stage["base"]
    check(base.startswith("rust:") and "bookworm" in base, f"builder is {base} (bookworm glibc)")
    bindir = os.path.join(work, "builder-usr-local-bin")
    shutil.rmtree(bindir, ignore_errors=True)
    os.makedirs(bindir)
    cargo_home = os.path.join(work, "cargo-home")
    shutil.rmtree(cargo_home, ignore_errors=True)
    os.makedirs(cargo_home)
    home = os.path.expanduser("~")
    env = {
        "PATH": os.path.join(home, ".cargo/bin") + ":" + DEFAULT_PATH,
        "HOME": home,
        "RUSTUP_HOME": os.environ.get("RUSTUP_HOME", os.path.join(home, ".rustup")),
        "CARGO_HOME": cargo_home,
        "TERM": "dumb",
    }
    run(["rustc", "--version"], env=env, cwd=ctx)
    for op, rest in stage["instrs"]:
        if op == "WORKDIR":
            log(f"builder WORKDIR {rest} is the context copy {ctx}")
        elif op == "COPY":
            if rest.split() != [".", "."]:
                sys.exit(f"docker-emulate: builder COPY {rest} is not emulated")
        elif op == "RUN":
            script = f"mount --bind {bindir} {BUILDER_BIN} && cd {ctx} && exec sh -c \"$1\""
            t = time.time()
            run(
                ["nice", "-n", str(nice), "unshare", "--mount", "--propagation", "private",
                 "sh", "-c", script, "sh", rest],
                env=env,
            )
            log(f"builder RUN took {time.time() - t:.0f} s")
        elif op == "ENV":
            env.update(parse_env(rest))
    return {"bindir": bindir, "ctx": ctx}


def builder_path(builder, p):
    if p.startswith(BUILDER_BIN + "/"):
        return os.path.join(builder["bindir"], p[len(BUILDER_BIN) + 1 :])
    sys.exit(f"docker-emulate: COPY --from=builder {p} is outside {BUILDER_BIN}")


# ---------------------------------------------------------------- runtime stages


def apt_mirror():
    for name in ["/etc/apt/sources.list.d/debian.sources"]:
        if os.path.exists(name):
            for line in open(name):
                if line.startswith("URIs:") and "security" not in line:
                    return line.split()[1]
    if os.path.exists("/etc/apt/sources.list"):
        for line in open("/etc/apt/sources.list"):
            w = line.split()
            if len(w) > 2 and w[0] == "deb" and "security" not in w[1]:
                return w[1] if not w[1].startswith("[") else w[2]
    return "http://deb.debian.org/debian"


def base_rootfs(work, mirror, nice):
    rootfs = os.path.join(work, "rootfs-bookworm-minbase")
    if os.path.exists(os.path.join(rootfs, ".complete")):
        log(f"reusing {rootfs}")
        return rootfs
    shutil.rmtree(rootfs, ignore_errors=True)
    run(["nice", "-n", str(nice), "debootstrap", "--variant=minbase", "bookworm", rootfs, mirror])
    open(os.path.join(rootfs, ".complete"), "w").close()
    return rootfs


def chroot_env(stage_env, home):
    env = {"PATH": DEFAULT_PATH, "HOSTNAME": "emulated", "HOME": home}
    env.update(stage_env)
    return env


def passwd_entry(root, user):
    """USER name, uid, name:group or uid:gid -> (uid, gid, home), as in the stage's files."""
    user, _, group = user.partition(":")
    with open(os.path.join(root, "etc/passwd")) as f:
        for line in f:
            w = line.strip().split(":")
            if user in (w[0], w[2]):
                gid = int(w[3])
                if group:
                    gid = int(group) if group.isdigit() else group_id(root, group)
                return int(w[2]), gid, w[5]
    sys.exit(f"docker-emulate: USER {user} is not in the stage's /etc/passwd")


def assemble_stage(stage, base, builder, work):
    root = os.path.join(work, "stage-" + stage["name"])
    shutil.rmtree(root, ignore_errors=True)
    run(["cp", "-a", base, root])
    img = {"root": root, "env": {}, "user": None, "entrypoint": None, "copied": []}
    for op, rest in stage["instrs"]:
        if op == "RUN":
            cmd = ["chroot"] + userspec(img) + [root, "/bin/sh", "-c", rest]
            run(cmd, env=chroot_env(img["env"], "/root"))
        elif op == "COPY":
            words = shlex.split(rest)
            if not words[0].startswith("--from=builder"):
                sys.exit(f"docker-emulate: COPY {rest} is not emulated")
            *srcs, dest = words[1:]
            for s in srcs:
                target = os.path.join(root, dest.lstrip("/"))
                if dest.endswith("/"):
                    target = os.path.join(target, os.path.basename(s))
                shutil.copy2(builder_path(builder, s), target)
                img["copied"].append(os.path.join(dest, os.path.basename(s)))
        elif op == "ENV":
            img["env"].update(parse_env(rest))
        elif op == "USER":
            img["user"] = rest
        elif op == "ENTRYPOINT":
            img["entrypoint"] = json.loads(rest)
        # WORKDIR, VOLUME, EXPOSE: nothing to do in a chroot for these stages.
    for b in img["copied"]:
        out = subprocess.run(["chroot", root, "ldd", b], capture_output=True, text=True)
        libs = [ln.split()[0] for ln in out.stdout.splitlines() if "=>" in ln or "ld-linux" in ln]
        check(out.returncode == 0 and "not found" not in out.stdout,
              f"{stage['name']}: ldd {b}: {' '.join(libs)}")
    return img


def group_id(root, name):
    with open(os.path.join(root, "etc/group")) as f:
        for line in f:
            w = line.strip().split(":")
            if w[0] == name:
                return int(w[2])
    sys.exit(f"docker-emulate: group {name} is not in the stage's /etc/group")


def userspec(img):
    if not img["user"]:
        return []
    uid, gid, _ = passwd_entry(img["root"], img["user"])
    return [f"--userspec={uid}:{gid}", f"--groups={gid}"]


# ---------------------------------------------------------------- running the images


def start(img, args=(), env=(), log_name="x"):
    """`docker run IMAGE args` with `-e` env: ENTRYPOINT + args as the image's user."""
    home = passwd_entry(img["root"], img["user"])[2] if img["user"] else "/root"
    e = chroot_env(img["env"], home)
    e.update(dict(env))
    out = open(os.path.join(os.path.dirname(img["root"]), log_name + ".log"), "w")
    cmd = ["chroot"] + userspec(img) + [img["root"]] + img["entrypoint"] + list(args)
    print("$ " + " ".join(f"{k}={v}" for k, v in dict(env).items()) + " " + " ".join(cmd))
    p = subprocess.Popen(cmd, env=e, stdout=out, stderr=subprocess.STDOUT)
    p.log_path = out.name
    return p


def tail(p, n=15):
    with open(p.log_path) as f:
        return "".join(f.readlines()[-n:])


NO_PROXY = urllib.request.build_opener(urllib.request.ProxyHandler({}))


def http(method, url, body=None, headers=None):
    req = urllib.request.Request(url, data=body, method=method, headers=headers or {})
    try:
        with NO_PROXY.open(req, timeout=30) as r:
            return r.status, {k.lower(): v for k, v in r.headers.items()}, r.read()
    except urllib.error.HTTPError as e:
        return e.code, {k.lower(): v for k, v in e.headers.items()}, e.read()


def wait_healthy(base, p, secs=30):
    end = time.time() + secs
    while time.time() < end:
        if p.poll() is not None:
            return False
        try:
            if http("GET", base + "/healthz")[0] == 200:
                return True
        except OSError:
            pass
        time.sleep(0.2)
    return False


def wait_done(base, job, secs):
    end = time.time() + secs
    while time.time() < end:
        _, _, b = http("GET", f"{base}/jobs/{job}")
        j = json.loads(b)
        if j["state"] in ("done", "failed", "cancelled"):
            return j
        time.sleep(0.5)
    return j


def png_ok(data):
    """Signature, chunk CRCs, IHDR, and IDAT inflating to exactly the image's size."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return False, "no PNG signature"
    pos, idat, ihdr = 8, b"", None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])
        if zlib.crc32(kind + body) != crc:
            return False, f"bad CRC in {kind}"
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
        if kind == b"IEND":
            break
    w, h, depth, colour = ihdr[:4]
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    raw = zlib.decompress(idat)
    want = h * (1 + w * channels * depth // 8)
    return len(raw) == want, f"{w}x{h}, {depth}-bit, colour type {colour}"


def stop(p, secs=40):
    p.send_signal(signal.SIGTERM)
    try:
        return p.wait(secs)
    except subprocess.TimeoutExpired:
        p.kill()
        return "killed"


def smoke(images, work):
    svc, wrk = images["service"], images["worker"]
    for img in (svc, wrk):
        for fs, how in (("proc", ["-t", "proc", "proc"]), ("sys", ["--rbind", "-o", "ro", "/sys"]),
                        ("dev", ["--rbind", "/dev"])):
            run(["mount"] + how + [os.path.join(img["root"], fs)])
    run(["ip", "link", "set", "lo", "up"])
    port = svc["env"]["TESSERA_LISTEN"].rsplit(":", 1)[1]
    base = f"http://127.0.0.1:{port}"
    scene = open(os.path.join(ROOT, "examples/thesis.ray"), "rb").read()

    # tessera-render from the worker image: the reference image.
    shutil.copy(os.path.join(ROOT, "examples/thesis.ray"), os.path.join(wrk["root"], "tmp"))
    ref = dict(wrk, entrypoint=["tessera-render"])
    r = start(ref, ["/tmp/thesis.ray", "-o", "/tmp/thesis.png"], log_name="render")
    check(r.wait(300) == 0, "worker image: tessera-render /tmp/thesis.ray -o /tmp/thesis.png")
    reference = open(os.path.join(wrk["root"], "tmp/thesis.png"), "rb").read()

    log("docker run tessera-service (image ENV only)")
    p = start(svc, log_name="service-refuse")
    try:
        code = p.wait(20)
    except subprocess.TimeoutExpired:
        code = stop(p)
    check(code not in (0, "killed") and "TESSERA_SUBMIT_TOKEN" in tail(p),
          f"refuses to start without a submit choice (exit {code}): {tail(p, 1).strip()}")

    log("docker run -e TESSERA_OPEN_SUBMIT=true tessera-service")
    p = start(svc, env={"TESSERA_OPEN_SUBMIT": "true"}, log_name="service-local")
    check(wait_healthy(base, p), "GET /healthz 200")
    st, _, page = http("GET", base + "/")
    check(st == 200 and b"<html" in page.lower(), "GET / serves the page")
    st, hdr, b = http("POST", base + "/jobs", scene)
    check(st == 201, f"POST /jobs examples/thesis.ray: {st} Location {hdr.get('location')}")
    job1 = json.loads(b)["id"]
    j = wait_done(base, job1, 300)
    check(j["state"] == "done", f"job {job1}: {j['state']}, {j['tiles_done']}/{j['tiles_total']}")
    workers = json.loads(http("GET", base + "/workers")[2])
    check(workers and sum(w.get("tiles_done", 0) for w in workers) == j["tiles_total"],
          f"{len(workers)} local workers rendered the tiles")
    st, hdr, png = http("GET", f"{base}/jobs/{job1}/image.png")
    ok, what = png_ok(png)
    check(st == 200 and hdr.get("content-type") == "image/png" and ok, f"image.png valid: {what}")
    check(png == reference, "image.png byte-identical to tessera-render's")
    check(stop(p) == 0, "SIGTERM: service exits 0")
    uid = passwd_entry(svc["root"], svc["user"])[0]
    check(os.stat(os.path.join(svc["root"], "data/tessera.db")).st_uid == uid != 0,
          f"database in /data, owned by the image's user (uid {uid})")

    log("docker run -e TESSERA_SUBMIT_TOKEN=S -e TESSERA_WORKER_TOKEN=T -e TESSERA_LOCAL_WORKERS=0"
        " tessera-service; docker run tessera-worker --server ... --token T")
    p = start(svc, env={"TESSERA_SUBMIT_TOKEN": "S", "TESSERA_WORKER_TOKEN": "T",
                        "TESSERA_LOCAL_WORKERS": "0"}, log_name="service-remote")
    check(wait_healthy(base, p), "GET /healthz 200 after restart")
    st, _, b = http("GET", f"{base}/jobs/{job1}/image.png")
    check(st == 200 and b == png, "the first job's PNG is still there after the restart (/data)")
    check(http("POST", base + "/jobs", scene)[0] == 401, "POST /jobs without the token: 401")
    st, _, b = http("POST", base + "/jobs", scene, {"Authorization": "Bearer S"})
    check(st == 201, f"POST /jobs with the submit token: {st}")
    job2 = json.loads(b)["id"]
    w = start(wrk, ["--server", base, "--token", "T", "--name", "emulated-worker"],
              log_name="worker")
    j = wait_done(base, job2, 300)
    check(j["state"] == "done", f"job {job2}: {j['state']}, {j['tiles_done']}/{j['tiles_total']}")
    workers = json.loads(http("GET", base + "/workers")[2])
    mine = [x for x in workers if x["name"] == "emulated-worker"]
    check(mine and mine[0]["tiles_done"] == j["tiles_total"],
          f"the worker container claimed and rendered all {j['tiles_total']} tiles")
    st, _, b = http("GET", f"{base}/jobs/{job2}/image.png")
    check(st == 200 and b == reference, "its image.png is byte-identical to tessera-render's")
    t = time.time()
    check(stop(w) == 0, f"SIGTERM: worker exits 0 ({time.time() - t:.1f} s)")
    check(stop(p) == 0, "SIGTERM: service exits 0")
    print(tail(w, 3), end="")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="/tmp/tessera-docker-emulate",
                    help="scratch folder (the debootstrapped rootfs is kept there for reuse)")
    ap.add_argument("--mirror", default=None, help="Debian mirror (default: the one apt uses)")
    ap.add_argument("--skip-build", action="store_true",
                    help="reuse the binaries of the last run's builder stage")
    ap.add_argument("--nice", type=int, default=15)
    ap.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)  # inner step
    a = ap.parse_args()
    if os.geteuid() != 0:
        sys.exit("docker-emulate: needs root (chroot, mount, unshare, debootstrap)")
    work = os.path.abspath(a.work)
    os.makedirs(work, exist_ok=True)
    stages = parse_dockerfile(os.path.join(ROOT, "Dockerfile"))
    by_name = {s["name"]: s for s in stages}
    state_file = os.path.join(work, "images.json")

    if a.smoke:  # inside a fresh network, mount and pid namespace
        images = json.load(open(state_file))
        smoke(images, work)
        print(f"{passed} passed, {failed} failed")
        sys.exit(1 if failed else 0)

    ctx = os.path.join(work, "context")
    if a.skip_build:
        builder = {"bindir": os.path.join(work, "builder-usr-local-bin"), "ctx": ctx}
    else:
        log("build context")
        assemble_context(ctx)
        log("builder stage")
        builder = build(by_name["builder"], ctx, work, a.nice)
    log("runtime stages")
    base = base_rootfs(work, a.mirror or apt_mirror(), a.nice)
    images = {}
    for s in stages:
        if s["name"] != "builder":
            check(s["base"] == "debian:bookworm-slim", f"{s['name']} stage on {s['base']}")
            images[s["name"]] = assemble_stage(s, base, builder, work)
    json.dump(images, open(state_file, "w"))
    log("running the images (private network: loopback only, like a container)")
    inner = subprocess.run(["unshare", "--net", "--mount", "--pid", "--fork", "--propagation",
                            "private", sys.executable, os.path.abspath(__file__), "--smoke",
                            "--work", work])
    print(f"{passed} passed, {failed} failed (outside the run step)")
    sys.exit(1 if failed or inner.returncode else 0)


if __name__ == "__main__":
    main()
