// surfcast-build's --help: every mode and option, what the README's usage
// lines point to. Kept apart from surfcast_build.cpp, which wires the modes.
#pragma once

inline constexpr const char* kBuildUsage = R"(usage: surfcast-build [options] INPUT... -o OUT      (INPUT: a file, a folder, or @LIST)
       surfcast-build --default-scene -o OUT
       surfcast-build --add INPUT... | --remove NAME... | --replace OLD NEW  --to SET
       surfcast-build --compact SET
       surfcast-build --merge SET1 SET2... [options] -o OUT
       surfcast-build --info SET            (SET: a folder, an http(s) or s3:// URL)
       surfcast-build scan|count --work W --part P/N [options] INPUT... -o OUT
       surfcast-build plan --work W [--parts N] [options] INPUT... -o OUT
       surfcast-build distribute --work W [--part P] [--header ...]
       surfcast-build chunk --work W I...
       surfcast-build merge --work W        (a build in stages: see below)
       surfcast-build update-plan --work W --add INPUT... | --remove NAME... | --replace OLD NEW  --to SET
       surfcast-build update-merge --work W (an update in stages: chunk between them)

Builds a level-of-detail tile set (tileset.json, hierarchy.bin, blocks.bin)
from point clouds and meshes. Inputs: PLY (points, or meshes with faces or
triangle strips), LAS 1.0-1.4 and LAZ (COPC too), E57 (every scan, posed; its
normals face each scan's scanner), PCD, text columns (.xyz .txt .pts .csv),
meshes in OBJ/OFF/STL through OpenMesh, and glTF. Several inputs merge into one tile set. A
folder stands for every readable file under it; @LIST for the paths listed in
the text file LIST, one per line. A point file may be an http(s) URL, read by
ranges from any host that honours Range (a presigned URL's query string is
never shown or stored), or an s3:// object; s3://BUCKET/PREFIX/ stands for
every readable object under the prefix. Meshes are read from local files.
S3 credentials, region and endpoint come from the standard AWS variables and
files (docs/STORAGE.md).

  -o, --output DIR        tile set folder to write (replaced atomically), or
                          s3://BUCKET/PREFIX: a new prefix of an S3 bucket
                          (built in $TMPDIR, then uploaded; docs/STORAGE.md)
  --default-scene         add the built-in scanned scene (about 1.5 M points)
  --scene-points N        points of the built-in scene (default 1500000)
  --seed N                seed of the built-in scene and mesh sampling (default 1)
  --add INPUT... --to SET add scans to a set in place: only the chunks the new
                          points reach and the levels above them are built again;
                          every other node keeps its bytes and byte range, the new
                          blocks are appended and tileset.json switched last, so
                          readers see the old set or the new one (README, "Updating
                          a set"). The options are the set's own (its build record);
                          only --threads and -q may be given. SET may be
                          s3://BUCKET/PREFIX: the new version is uploaded, then
                          tileset.json switched only if no other update did first
                          (docs/STORAGE.md, "Updates")
  --remove NAME... --to SET
                          remove the points of the set's inputs NAME (a path, or a
                          file name only one input has), in place alike
  --replace OLD NEW --to SET
                          remove input OLD's points and add NEW's, in one update
  --merge SET1 SET2... -o OUT
                          join tile sets built apart into one: a build from
                          their points (each set's leaves: positions, normals,
                          colours, attributes), with SET1's build options (its
                          build record) and then the command line's; each set is
                          one input of the joined set (--remove takes it out
                          again). A tile set's folder (or s3:// prefix) is an
                          input anywhere
  --compact SET           write the set anew without the blocks its updates
                          replaced (replaced atomically, as a rebuild is: byte
                          ranges change, node ETags do not); a set in a bucket
                          gets the compacted blocks as its next version
  --preview               first publish a preview to OUT, unless OUT holds a set
                          (whose viewers keep it until the build replaces it): a set
                          of every Nth point of each input, about 200,000 points,
                          marked "preview" in its tileset.json, for viewers to open
                          and follow (surfcast-view --follow, ?follow=) while the
                          build goes on; the build then replaces it. The build's
                          own bytes are those it writes without --preview
  --preview-points N      --preview of about N points (default 200000)
  --info SET              print a tile set's summary and verify every checksum; with
                          a URL, --header 'NAME: VALUE' (repeatable), --token-file F,
                          --redirect-credentials, --ca-file F and --insecure say how
                          to reach it, as in surfcast-view (and inputs at URLs)
  --grid G                cells per axis of a node's finest sampling grid (default 128)
  --page-depth D          levels per hierarchy page, which a viewer fetches as it
                          reaches them (default 5)
  --capacity N            surfels above which a node splits (default 20000, at most 4194304)
  --memory SIZE           peak memory budget, e.g. 512M, 2G (default 2G)
  --threads N             worker threads (default: all cores)
  --normal-k K            neighbours for normal estimation (default 16)
  --spacing-k K           k of the k-th-neighbour spacing h (default 8)
  --position-fraction F   resampled levels: quantization step = cell / F (default 8)
  --normal-bits N         Draco quantization bits per normal component (default 8)
  --no-radius             no per-surfel radius, even where a node's sampling is irregular
  --isolation T           isolated surfels (a stray return, a leaf hit by a few points)
                          are drawn at their level's spacing rho (2 sampling cells), not
                          as discs reaching their far neighbours: those whose k-th
                          neighbour (--spacing-k) lies beyond T rho, or beyond rho
                          among neighbours scattered off a plane (default 6, measured:
                          see bench/BENCHMARKS.md; 0: off, as --no-radius makes it)
  --kernel-scale K        reconstruction kernel V^r = (K h)^2 I the weights assume
                          (default 0.5, measured: see bench/BENCHMARKS.md)
  --weights MODE          none (default: ewa-pixel, the default renderer mode, reads
                          no weights), analytic (for ewa-surfel), or capture
                          (rendered on Vulkan, Ren 2002 §7.2; see surfcast-weights)
  --attributes LIST       attributes to store: a comma-separated list of names; all;
                          or none. Default: intensity, classification, return_number
                          and number_of_returns, each where some input carries it and
                          it varies across the set (LAS/LAZ: all four; PLY/PCD/text:
                          intensity, classification where a field holds them). On
                          request: LAS/LAZ scan_angle, user_data, point_source_id,
                          gps_time, nir and Extra Bytes dimensions by name; PLY and
                          PCD properties by name; E57 row and column
  --opacity A             multiply every point's opacity by A in [0, 1] (all inputs);
                          the set stores opacity only where some point is translucent
                          (PLY alpha/opacity properties; see --read-alpha)
  --read-alpha            PCD: take the packed colour's top byte (rgba's alpha) as
                          opacity; off by default, as many PCD files leave junk there
  --columns LAYOUT        text layout, e.g. x,y,z,r,g,b or x,y,z,_,nx,ny,nz
  --mesh-spacing S        mesh sampling spacing (default: one surfel per texel on a
                          textured mesh, else half the median edge; coarsened where
                          that would exceed --mesh-max-surfels)
  --mesh-max-surfels N    most surfels a mesh gives at its default spacing (5000000)
  --texture-filter F      colours of textured meshes' surfels, on every level: optimal
                          (least-squares coefficients for the renderer's kernels;
                          default), ewa (the texture filtered with each surfel's
                          kernel: faster to build, blurrier) or nearest (the texture
                          at each leaf's centre, averaged above)
  --allow-missing-textures
                          a diffuse texture (OBJ map_Kd) that is missing or unreadable
                          is a warning, its faces take vertex colours (default: error)
  --allow-outside-paths   let a mesh's external files (glTF buffers and images, OBJ
                          material libraries and maps, PLY TextureFile) lie outside
                          its folder (default: an error naming the file, so that a
                          model from elsewhere cannot read any file you can)
  --vertices-only         read a mesh file's vertices as points, no sampling
  -q, --quiet             no progress output
  -h, --help              this text

A build in stages runs as separate commands, each its own process, on any
machines that see the inputs and the work folder W; the set is the same bytes
as one surfcast-build. plan takes the inputs and options and writes W/plan.bin
and W/plan.json (the chunk count and each chunk's points); distribute, chunk
and merge read them, and take only --work, --threads and -q (distribute also
--part). chunk builds the chunks named (0 to the count less one), in any order
and any grouping; merge writes the set at plan's -o, then removes the parts'
and chunks' files from W. plan scans and counts the inputs itself, or, with
--parts N, reduces what scan and count wrote for parts 0/N to N-1/N (runs of
consecutive inputs of about equal bytes; count runs once every scan is done);
distribute --part P then reads part P alone. How to reach URL inputs
(--header, --token-file, --ca-file, --insecure) is never stored in the plan:
give it to each stage that reads inputs (scan, count, plan, distribute).

An update in stages: update-plan does all that precedes the chunks' builds
(the scan and count of the added inputs, the removed points found, the set's
points near the change and the added ones distributed) and writes W/plan.json
with "build", the chunks to build; chunk builds them; update-merge builds the
levels above and switches the set, as --add, --remove and --replace do in one
process, with the same bytes. It fails, leaving the set as it is, where the
set changed after update-plan.
)";
