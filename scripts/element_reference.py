#!/usr/bin/env python3
"""The element reference (docs/ELEMENTS.md), made from the elements themselves.

Each element's doc block (the SECTION comment at the top of gst/<element>.cpp: what it does,
launch lines) and what gst-inspect-1.0 shows of it from the registry (pads, properties with
their type, range or values, default and description, action signals) become one section.

  element_reference.py --write   regenerate docs/ELEMENTS.md
  element_reference.py --check   fail when docs/ELEMENTS.md differs from what --write would write,
                                 or when a default it gives is not the one gst-inspect-1.0 shows
  element_reference.py --run     run every doc launch line, shortened: 4 panoramas (identity
                                 eos-after behind the last stitch element, which also counts
                                 them), fakesink for the screen, files written to a temporary
                                 folder; lines needing elements this machine lacks (nvh264dec,
                                 cudadownload without a GPU) are skipped and listed. Fails on any
                                 error, and on a line that makes no panorama.
  element_reference.py --expect-no-panorama LINE
                                 the test of the test: succeeds when --run would fail LINE for
                                 making no panorama.
Needs GST_PLUGIN_PATH at the built plugin (meson's test environment sets it) and gst-python
(Debian's python3-gst-1.0).
"""
import argparse
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time

import gi

gi.require_version("Gst", "1.0")
from gi.repository import GObject, Gst  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
ELEMENTS = ["stitchsync", "stitchsyncaudio", "stitchcalib", "stitchcolor", "stitchflowwarp", "stitchblend", "stitchbin", "stitch360sink"]
SOURCES = {"stitchsync": "gststitchsync.cpp", "stitchsyncaudio": "gststitchsyncaudio.cpp", "stitchcalib": "gststitchcalib.cpp", "stitchcolor": "gststitchcolor.cpp",
           "stitchflowwarp": "gststitchflowwarp.cpp", "stitchblend": "gststitchblend.cpp",
           "stitchbin": "gststitchbin.cpp", "stitch360sink": "gststitch360sink.cpp"}
DOC = os.path.join(ROOT, "docs", "ELEMENTS.md")
FRAMES = 4  # per input, when --run shortens a launch line
COUNTER = "stitch_output"  # the identity --run puts behind the last stitch element


def doc_block(element):
    """(paragraphs as Markdown, [launch line, ...]) from the element's SECTION comment."""
    text = open(os.path.join(ROOT, "gst", SOURCES[element])).read()
    m = re.search(r"/\*\*\n(.*?)\*/", text, re.S)
    lines = [re.sub(r"^ \* ?", "", l) for l in m.group(1).split("\n")]
    lines = [l for l in lines if not l.startswith(("SECTION:", "@title:"))]
    out, launches, code = [], [], None
    for l in lines:
        if l.strip() == "|[":
            code = []
        elif l.strip() == "]|":
            launches.append(" ".join(c.strip().rstrip("\\").strip() for c in code))
            out.append("```sh\n" + "\n".join(code) + "\n```")
            code = None
        elif code is not None:
            code.append(l)
        else:
            out.append(l)
    return "\n".join(out).strip() + "\n", launches


def value_text(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "%g" % v
    if isinstance(v, Gst.Fraction):
        return "%d/%d" % (v.num, v.denom)
    if v is None:
        return "null"
    if hasattr(v, "value_nick"):
        return v.value_nick
    if hasattr(v, "first_value_nick"):  # flags
        return str(v.first_value_nick) if int(v) else "(none)"
    return str(v)


def property_rows(element):
    factory = Gst.ElementFactory.find(element)
    e = factory.create(None)
    base = set(p.name for p in GObject.ObjectClass.list_properties(Gst.Element)) | {"name", "parent"}
    rows, defaults = [], {}
    for p in sorted(e.list_properties(), key=lambda p: p.name):
        if p.name in base or p.owner_type.name in ("GstObject", "GstElement", "GstBin", "GstBaseTransform"):
            continue
        t = p.value_type
        kind = GObject.type_name(t)
        if p.value_type.is_a(GObject.TYPE_ENUM) and t != GObject.TYPE_ENUM:
            kind = "enum: " + ", ".join("`%s`" % v.value_nick for _, v in sorted(p.enum_class.__enum_values__.items()))
        elif p.value_type.is_a(GObject.TYPE_FLAGS) and t != GObject.TYPE_FLAGS:
            kind = "flags: " + ", ".join("`%s`" % v.first_value_nick for k, v in sorted(p.flags_class.__flags_values__.items())
                                         if bin(k).count("1") == 1) + " (combined with +)"
        elif hasattr(p, "minimum") and hasattr(p, "maximum"):
            kind = "%s %s to %s" % (kind, value_text(p.minimum), value_text(p.maximum))
        # When it may change, as gst-inspect-1.0 says (flags)
        when = []
        if p.flags & GObject.ParamFlags.CONSTRUCT_ONLY:
            when.append("construct-only")
        elif p.flags & Gst.PARAM_MUTABLE_PLAYING:
            when.append("changeable while playing")
        elif p.flags & Gst.PARAM_MUTABLE_PAUSED:
            when.append("changeable up to PAUSED")
        elif p.flags & Gst.PARAM_MUTABLE_READY:
            when.append("changeable up to READY")
        if p.flags & Gst.PARAM_CONTROLLABLE:
            when.append("controllable")
        if when:
            kind += " (%s)" % ", ".join(when)
        # What a new element holds, as gst-inspect-1.0 shows it (not the spec's default: a
        # GstFraction spec has none that Python can read, and an element may start elsewhere).
        default = e.get_property(p.name)
        if kind.startswith("enum"):
            default = p.enum_class.__enum_values__[int(default)].value_nick
        elif kind.startswith("flags"):
            default = "+".join(v.first_value_nick for k, v in sorted(p.flags_class.__flags_values__.items())
                               if k and (int(default) & k) == k and bin(k).count("1") == 1) or "(none)"
        else:
            default = value_text(default)
        defaults[p.name] = default
        rows.append("| `%s` | %s | `%s` | %s |" % (p.name, kind, default, p.blurb.replace("|", "\\|")))
    pads = []
    for t in sorted(factory.get_static_pad_templates(), key=lambda t: t.name_template):
        # System-memory caps only, so that builds with and without CUDA document alike.
        all_caps, caps = t.get_caps(), Gst.Caps.new_empty()
        for i in range(all_caps.get_size()):
            features = all_caps.get_features(i)
            if not (features and not features.is_any() and features.contains("memory:CUDAMemory")):
                caps.append_structure(all_caps.get_structure(i).copy())
        caps = caps.to_string()
        caps = caps if len(caps) < 90 else caps[:87] + "..."
        presence = {Gst.PadPresence.ALWAYS: "always", Gst.PadPresence.REQUEST: "request",
                    Gst.PadPresence.SOMETIMES: "sometimes"}[t.presence]
        pads.append("| `%s` | %s, %s | `%s` |" % (t.name_template, "sink" if t.direction == Gst.PadDirection.SINK else "src",
                                                 presence, caps))
    signals = [GObject.signal_name(s) for s in GObject.signal_list_ids(type(e))]
    property_rows.defaults[element] = defaults
    return factory, rows, pads, signals


property_rows.defaults = {}  # element -> {property: default as documented}


def inspect_defaults(element):
    """{property: default} as gst-inspect-1.0 prints them."""
    out = subprocess.run(["gst-inspect-1.0", element], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                         text=True).stdout
    found, name = {}, None
    for line in out.splitlines():
        m = re.match(r"^  ([a-z][a-z0-9-]*)\s*: ", line)
        if m:
            name = m.group(1)
        m = re.search(r"Default: (.*)$", line)
        if m and name and name not in found:
            v = m.group(1).strip()
            q = re.search(r'"(.*)"$', v)  # enums and flags: 0, "auto"; strings: "text"
            found[name] = q.group(1) if q else v
    return found


def same_default(documented, inspected):
    if documented == inspected:
        return True
    try:
        return abs(float(documented) - float(inspected)) <= 1e-9 * max(1.0, abs(float(documented)))
    except ValueError:
        return False


def check_defaults():
    """Differences between the documented defaults and gst-inspect-1.0's, as lines."""
    bad = []
    for e, documented in property_rows.defaults.items():
        inspected = inspect_defaults(e)
        for name, d in documented.items():
            if name not in inspected:
                bad.append("%s::%s: gst-inspect-1.0 shows no default" % (e, name))
            elif not same_default(d, inspected[name]):
                bad.append("%s::%s: documented %s, gst-inspect-1.0 shows %s" % (e, name, d, inspected[name]))
    return bad


def render():
    Gst.init(None)
    missing = [e for e in ELEMENTS if not Gst.ElementFactory.find(e)]
    if missing:
        raise SystemExit("not in the registry: %s (set GST_PLUGIN_PATH to build/gst)" % ", ".join(missing))
    parts = ["# Element reference\n",
             "Generated by `scripts/element_reference.py --write` from each element's doc block and from "
             "what `gst-inspect-1.0` shows of it (a test fails when this file is stale; another runs every "
             "launch line below, shortened). Run the launch lines from the repository root with "
             "`export GST_PLUGIN_PATH=$PWD/build/gst`. Pads list their system-memory caps; in a build with "
             "CUDA every pad also takes the same in `video/x-raw(memory:CUDAMemory)`. A property's type says "
             "when it may change (no mention: before the element starts) and whether a GstControlSource may "
             "drive it; its default is what a new element holds, as gst-inspect-1.0 shows it.\n",
             "\n".join("- [`%s`](#%s)" % (e, e) for e in ELEMENTS) + "\n"]
    for e in ELEMENTS:
        text, _ = doc_block(e)
        factory, rows, pads, signals = property_rows(e)
        parts.append("## %s\n" % e)
        parts.append("*%s* (%s): %s\n" % (factory.get_metadata("long-name"), factory.get_metadata("klass"),
                                          factory.get_metadata("description")))
        parts.append(text)
        parts.append("### Pads\n\n| template | direction | caps |\n|---|---|---|\n" + "\n".join(pads) + "\n")
        parts.append("### Properties\n\n| property | type | default | description |\n|---|---|---|---|\n"
                     + "\n".join(rows) + "\n")
        if signals:
            parts.append("### Action signals\n\n" + "\n".join("- `%s`" % s for s in signals) + "\n")
    return "\n".join(parts)


def shortened(line, tmp):
    """The launch line as the test runs it, or None with the reason when it cannot run here."""
    args = shlex.split(line)
    if args[0] != "gst-launch-1.0":
        return None, "not a gst-launch-1.0 line"
    args = [a for a in args[1:] if a not in ("-e", "-q", "-v")]
    out = []
    for a in args:
        name = a.split(" ")[0]
        if "=" not in a and a not in ("!",) and "." not in a and not Gst.ElementFactory.find(name) \
                and not name.startswith("video/") and not name.startswith("audio/"):
            return None, "needs %s" % name
        if a.startswith("location=") and not a.startswith("location=data/"):
            a = "location=" + os.path.join(tmp, os.path.basename(a.split("=", 1)[1]))
        elif a.startswith(("save-file=", "load-file=")) and a.split("=", 1)[1].startswith("/tmp/"):
            key, path = a.split("=", 1)
            a = key + "=" + os.path.join(tmp, os.path.basename(path))
        out.append(a)
        if a == "autovideosink":
            out[-1] = "fakesink"
        elif a == "videotestsrc":
            out.append("num-buffers=%d" % FRAMES)
    # Behind the stitcher (the chain of stitch elements the line starts with), an identity counts
    # what it outputs (-v prints each buffer) and ends the stream after FRAMES of them.
    end, i = 0, 0
    while i < len(out):  # elements of the first chain: NAME [prop=value ...] ! NAME ...
        if out[i].startswith("stitch"):
            end = i + 1
            while end < len(out) and out[end] != "!" and "=" in out[end] and "." not in out[end].split("=")[0]:
                end += 1
            if end < len(out) and out[end] == "!":
                i = end + 1
                continue
        break
    counter = ["identity", "name=" + COUNTER, "silent=false", "eos-after=%d" % (FRAMES + 1)]
    if end:
        out[end:end] = ["!"] + counter
    else:  # a line that ends in a stitch sink (stitch360sink): count what reaches it
        sink = max(k for k, a in enumerate(out) if a.startswith("stitch") and "=" not in a)
        out[sink:sink] = counter + ["!"]
    if "cudadownload" in out or "nvh264dec" in out:
        if not has_cuda_device():
            return None, "needs a CUDA device"
    return ["gst-launch-1.0", "-e", "-v"] + out, None


def run_line(cmd):
    """(ok, what it printed, panoramas made): ok when it ran without an error and made any."""
    r = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=240)
    lines = r.stdout.splitlines()
    errors = [l for l in lines if l.startswith("ERROR")]
    made = sum(1 for l in lines if (COUNTER + ": last-message = chain") in l)
    return r.returncode == 0 and not errors and made > 0, r.stdout, made


def has_cuda_device():
    return Gst.ElementFactory.find("nvh264dec") is not None and os.path.exists("/dev/nvidia0")


def run_all():
    Gst.init(None)
    failures, skipped, ran = [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for e in ELEMENTS:
            for line in doc_block(e)[1]:
                cmd, why = shortened(line, tmp)
                if not cmd:
                    skipped.append("%s: %s (%s)" % (e, line[:80], why))
                    continue
                ran += 1
                t0 = time.time()
                ok, printed, made = run_line(cmd)
                status = "ok" if ok else "FAILED"
                print("%-6s %5.1f s  %d made  %s: %s" % (status, time.time() - t0, made, e, " ".join(cmd[3:])),
                      flush=True)
                if not ok:
                    errors = [l for l in printed.splitlines() if l.startswith(("ERROR", "WARNING"))]
                    failures.append("%s: %s\n%d made\n%s" % (e, " ".join(cmd), made, "\n".join(errors[-20:])))
    for s in skipped:
        print("skipped", s)
    print("%d launch lines ran, %d failed, %d skipped" % (ran, len(failures), len(skipped)))
    for f in failures:
        print("\n" + f, file=sys.stderr)
    return 1 if failures or ran == 0 else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--write", action="store_true")
    g.add_argument("--check", action="store_true")
    g.add_argument("--run", action="store_true")
    g.add_argument("--expect-no-panorama", metavar="LINE")
    args = ap.parse_args()
    if args.run:
        return run_all()
    if args.expect_no_panorama:
        Gst.init(None)
        with tempfile.TemporaryDirectory() as tmp:
            cmd, why = shortened(args.expect_no_panorama, tmp)
            if not cmd:
                print("cannot run here:", why)
                return 77
            ok, _, made = run_line(cmd)
        print("%s: %d made: %s" % (" ".join(cmd), made, "--run would pass it" if ok else "--run fails it, as it must"))
        return 1 if ok else 0
    text = render()
    if args.write:
        open(DOC, "w").write(text)
        print("wrote", DOC)
        return 0
    current = open(DOC).read() if os.path.exists(DOC) else ""
    bad = check_defaults()
    if bad:
        print("defaults differ from gst-inspect-1.0's:\n  " + "\n  ".join(bad), file=sys.stderr)
        return 1
    if current != text:
        print("docs/ELEMENTS.md is stale: run scripts/element_reference.py --write (with GST_PLUGIN_PATH=build/gst)",
              file=sys.stderr)
        import difflib
        sys.stderr.writelines(difflib.unified_diff(current.splitlines(True), text.splitlines(True), "docs/ELEMENTS.md",
                                                   "generated", n=1))
        return 1
    print("docs/ELEMENTS.md is up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
