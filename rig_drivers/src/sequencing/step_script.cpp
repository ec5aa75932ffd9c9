#include "rig_drivers/sequencing/step_script.hpp"

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace rig_drivers {
namespace {

struct Keyword {
  const char* word;
  StepKind kind;
  const char* unit;  ///< nullptr = takes no argument
};

constexpr Keyword kKeywords[] = {
    {"move_mm", StepKind::kMove, "mm"},       {"goto_mm", StepKind::kGoto, "mm"},
    {"speed_mm_s", StepKind::kSpeed, "mm/s"}, {"pitch_deg", StepKind::kPitch, "deg"},
    {"yaw_deg", StepKind::kYaw, "deg"},       {"wait_ms", StepKind::kWait, "ms"},
    {"frame", StepKind::kFrame, nullptr},
};

std::string fmt(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

bool parseNumber(const std::string& token, double* value) {
  if (token.empty()) return false;
  char* end = nullptr;
  *value = std::strtod(token.c_str(), &end);
  return end == token.c_str() + token.size() && std::isfinite(*value);
}

struct Frame {
  std::size_t first_step;  ///< index in steps where the block started
  long count;
  int line;
};

}  // namespace

std::vector<std::string> StepLimits::validate() const {
  std::vector<std::string> p;
  if (!(track_length_mm > 0)) p.push_back("track_length_mm must be > 0 (mm)");
  if (!(max_speed_mm_s > 0)) p.push_back("max_speed_mm_s must be > 0 (mm/s)");
  if (!(max_pitch_deg > 0 && max_pitch_deg <= 90)) p.push_back("max_pitch_deg must be in (0, 90]");
  if (!(max_yaw_deg > 0 && max_yaw_deg <= 180)) p.push_back("max_yaw_deg must be in (0, 180]");
  if (!(max_wait_ms > 0)) p.push_back("max_wait_ms must be > 0 (ms)");
  if (max_steps == 0) p.push_back("max_steps must be > 0");
  return p;
}

std::size_t StepScript::frameCount() const {
  std::size_t n = 0;
  for (const auto& s : steps) n += s.kind == StepKind::kFrame;
  return n;
}

std::size_t StepScript::motionCount() const {
  std::size_t n = 0;
  for (const auto& s : steps)
    n += s.kind == StepKind::kMove || s.kind == StepKind::kGoto || s.kind == StepKind::kPitch ||
         s.kind == StepKind::kYaw;
  return n;
}

const char* stepKeyword(StepKind kind) {
  for (const auto& k : kKeywords)
    if (k.kind == kind) return k.word;
  return "?";
}

StepScript parseStepScript(const std::string& text, const std::string& name,
                           const StepLimits& limits) {
  const auto limit_problems = limits.validate();
  if (!limit_problems.empty()) {
    std::string msg = name + ": invalid step limits:";
    for (const auto& p : limit_problems) msg += " " + p + ";";
    throw StepScriptError(msg, 0);
  }
  StepScript script;
  script.name = name;
  std::vector<Frame> open_blocks;
  std::istringstream in(text);
  std::string raw;
  int line_no = 0;
  auto fail = [&](const std::string& what) {
    throw StepScriptError(name + ":" + std::to_string(line_no) + ": " + what, line_no);
  };
  while (std::getline(in, raw)) {
    ++line_no;
    const auto hash = raw.find('#');
    if (hash != std::string::npos) raw.erase(hash);
    std::istringstream words(raw);
    std::vector<std::string> tok;
    for (std::string w; words >> w;) tok.push_back(w);
    if (tok.empty()) continue;
    const std::string& key = tok[0];

    if (key == "repeat") {
      double n = 0;
      if (tok.size() != 2 || !parseNumber(tok[1], &n) || n < 1 || n != std::floor(n) || n > 1e6)
        fail("'repeat' needs one whole count >= 1, e.g. 'repeat 100'");
      open_blocks.push_back({script.steps.size(), static_cast<long>(n), line_no});
      continue;
    }
    if (key == "end_repeat") {
      if (tok.size() != 1) fail("'end_repeat' takes no argument");
      if (open_blocks.empty()) fail("'end_repeat' without a matching 'repeat'");
      const Frame block = open_blocks.back();
      open_blocks.pop_back();
      if (block.first_step == script.steps.size())
        fail("empty 'repeat' block (opened on line " + std::to_string(block.line) + ")");
      const std::vector<Step> body(script.steps.begin() + block.first_step, script.steps.end());
      if (script.steps.size() + body.size() * (block.count - 1) > limits.max_steps)
        fail("script expands to more than " + std::to_string(limits.max_steps) + " steps");
      for (long i = 1; i < block.count; ++i)
        script.steps.insert(script.steps.end(), body.begin(), body.end());
      continue;
    }

    const Keyword* kw = nullptr;
    for (const auto& k : kKeywords)
      if (key == k.word) kw = &k;
    if (!kw) {
      std::string known;
      for (const auto& k : kKeywords) known += std::string(known.empty() ? "" : ", ") + k.word;
      fail("unknown step '" + key + "' (expected one of: " + known + ", repeat, end_repeat)");
    }
    Step step;
    step.kind = kw->kind;
    step.line = line_no;
    if (!kw->unit) {
      if (tok.size() != 1) fail("'" + key + "' takes no argument");
    } else {
      if (tok.size() != 2)
        fail("'" + key + "' needs exactly one number in " + kw->unit + ", e.g. '" + key + " 10'");
      if (!parseNumber(tok[1], &step.value))
        fail("'" + key + "': '" + tok[1] + "' is not a plain number in " + kw->unit +
             " (the unit is in the keyword)");
      const double v = step.value;
      switch (step.kind) {
        case StepKind::kMove:
          if (std::fabs(v) > limits.track_length_mm)
            fail("move_mm " + fmt(v) + " is longer than the track (" + fmt(limits.track_length_mm) +
                 " mm)");
          break;
        case StepKind::kGoto:
          if (v < 0 || v > limits.track_length_mm)
            fail("goto_mm " + fmt(v) + " is outside the track [0, " + fmt(limits.track_length_mm) +
                 "] mm");
          break;
        case StepKind::kSpeed:
          if (v < 0 || v > limits.max_speed_mm_s)
            fail("speed_mm_s " + fmt(v) + " is outside [0, " + fmt(limits.max_speed_mm_s) +
                 "] mm/s");
          break;
        case StepKind::kPitch:
          if (std::fabs(v) > limits.max_pitch_deg)
            fail("pitch_deg " + fmt(v) + " is outside +-" + fmt(limits.max_pitch_deg) + " deg");
          break;
        case StepKind::kYaw:
          if (std::fabs(v) > limits.max_yaw_deg)
            fail("yaw_deg " + fmt(v) + " is outside +-" + fmt(limits.max_yaw_deg) + " deg");
          break;
        case StepKind::kWait:
          if (v < 0 || v > limits.max_wait_ms)
            fail("wait_ms " + fmt(v) + " is outside [0, " + fmt(limits.max_wait_ms) + "] ms");
          break;
        case StepKind::kFrame:
          break;
      }
    }
    if (script.steps.size() >= limits.max_steps)
      fail("script has more than " + std::to_string(limits.max_steps) + " steps");
    script.steps.push_back(step);
  }
  if (!open_blocks.empty()) {
    line_no = open_blocks.back().line;
    fail("'repeat' is never closed by 'end_repeat'");
  }
  if (script.steps.empty()) throw StepScriptError(name + ": script has no steps", 0);
  return script;
}

StepScript loadStepScript(const std::string& path, const StepLimits& limits) {
  std::ifstream f(path);
  if (!f) throw StepScriptError("cannot read step script '" + path + "'", 0);
  std::stringstream ss;
  ss << f.rdbuf();
  return parseStepScript(ss.str(), path, limits);
}

}  // namespace rig_drivers
