// surfcast-build's command line (CLI11, common/command_line.h): a whole
// build, an update, --merge, --compact, --info, or one stage of a build in
// stages (a subcommand). Every option, its checks and its --help line are
// declared once, in build_cli.cpp.
#pragma once

#include <string>
#include <vector>

#include "octree_builder.h"

namespace surfcast {

// The command line, parsed. A later stage of a staged build parses the
// plan's stored command line (parseStoredCommandLine) and then its own.
struct BuildArgs {
    std::string stage;  // the subcommand ("" for a whole build, an update, ...)
    BuildOptions opt;
    bool captureWeights = false;
    std::string info;            // --info SET, reached as opt.inputs.http says
    std::string work;            // --work: a staged build's work folder
    std::vector<size_t> chunks;  // the chunk stage's chunks
    size_t part = 0, parts = 0;  // --part P/N (scan, count; P alone for distribute) and --parts N (plan)
    bool partGiven = false;
    uint32_t standIns = 0;  // --stand-ins N (distribute, refine): every Nth point stands in for a chunk not built yet
    // The build options as given, in order (every option but the inputs, -o,
    // the modes, the stages' own and how to reach URLs): what a plan and a
    // build record store, and what an update refuses but --threads and -q.
    std::vector<std::string> kept;
    // An update in place of the set --to names: --add INPUT..., --remove
    // NAME..., --replace OLD NEW (the positional arguments).
    std::string update;
    std::string to;
    std::string compact;               // --compact SET
    bool merge = false;                // --merge SET...: the positional arguments are tile sets
    bool preview = false;              // --preview: a preview of the build published to -o first
    uint64_t previewPoints = 200'000;  // --preview-points: about this many points make it
    double previewInterval = 2;        // --preview-interval: the least seconds between versions while building
};

// Parses surfcast-build's arguments (without the program's name) into
// `out`. Returns -1 to go on, or the exit status: 0 after --help or
// --version, 2 after a usage error (printed).
int parseBuildCommandLine(const std::vector<std::string>& args, BuildArgs* out);

// A plan's or build record's stored command line (storedCommandLine),
// parsed as the plan stage parses its own: -1 where it parses.
int parseStoredCommandLine(const std::vector<std::string>& args, BuildArgs* out);

// The command line a plan and a set's build record keep: the build options
// but -q and --threads N, which change no byte, then -o and the inputs.
std::vector<std::string> storedCommandLine(const BuildArgs& a);

}  // namespace surfcast
