// `pstream play FILE.pstream [more]`: a GLFW window with an orbit camera and a Dear ImGui panel —
// playback controls, statistics per stage, and the chunk cache view of each stream.
#include <epoxy/gl.h>
// GLFW after epoxy, which provides the GL declarations.
#include <GLFW/glfw3.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_opengl3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <numbers>

#include <fmt/format.h>

#include "commands.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "particlestream/stream.hpp"

namespace pstream::app {
namespace {

using Clock = std::chrono::steady_clock;

struct Orbit {
  render::Vec3 target{0, 0, 0};
  float yaw = 0.5f, pitch = 0.35f, distance = 5.0f;
  std::array<float, 2> shift{0, 0};  // the framing's lens shift: the clip beside the panel
  render::Camera camera() const {
    render::Camera c;
    c.target = target;
    c.shift = shift;
    c.eye = {target[0] + distance * std::cos(pitch) * std::sin(yaw), target[1] + distance * std::sin(pitch),
             target[2] + distance * std::cos(pitch) * std::cos(yaw)};
    c.near = distance * 0.01f;
    c.far = distance * 100.0f;
    return c;
  }
  // The library's automatic camera (the one `render` and the demo use), as an orbit around its
  // target.
  void frame(const render::Camera& c) {
    target = c.target;
    const float dx = c.eye[0] - c.target[0], dy = c.eye[1] - c.target[1], dz = c.eye[2] - c.target[2];
    distance = std::max(std::sqrt(dx * dx + dy * dy + dz * dz), 1e-3f);
    pitch = std::asin(std::clamp(dy / distance, -1.0f, 1.0f));
    yaw = std::atan2(dx, dz);
    shift = c.shift;
  }
};

// Where the panel and the timeline leave the picture free (Camera::framing's region), so that the
// clip is framed where nothing covers it (Viewer.NoParticleUnderThePanel checks it).
constexpr float kPanelX = 10, kPanelWidth = 320, kTimelineHeight = 44;
std::array<float, 4> free_region(int width, int height) {
  if (width <= 0 || height <= 0) return {0, 0, 1, 1};
  const float x0 = std::min((kPanelX + kPanelWidth + 10) / float(width), 0.5f);
  const float y1 = std::max(1.0f - kTimelineHeight / float(height), 0.5f);
  return {x0, 0.0f, 1.0f, y1};
}

struct Ui {
  Orbit orbit;
  playback::CameraTrack track;  // the automatic camera over the clip (render's), beside the panel
  bool follow = true;           // the camera follows the track until the user moves it; F resumes
  bool dragging_left = false, dragging_right = false;
  double last_x = 0, last_y = 0;
  float speed = 1.0f, size = 1.0f;
  bool loop = true;
  bool show_ui = true;                       // the panel and the timeline (H)
  int sort_mode = 1;                         // none, back to front, front to back
  int blend = 0;                             // alpha, additive, alpha test
  int look = 0;                              // sprites, liquid
  int liquid_filter = 0, liquid_output = 0;  // in the order of the combos below
  bool backdrop = false;
  float background[3] = {render::kDefaultBackground[0], render::kDefaultBackground[1], render::kDefaultBackground[2]};
  playback::Player* player = nullptr;
};

void step_frames(playback::Player& player, int delta) {
  for (std::size_t i = 0; i < player.clip_count(); ++i) {
    stream::ParticleStream& clip = player.clip(i);
    const auto& m = clip.metadata();
    if (m.frame_count() == 0) continue;
    const auto f = static_cast<std::int64_t>(clip.frame().frame) + delta;
    const auto clamped = static_cast<std::uint64_t>(std::clamp<std::int64_t>(f, 0, std::int64_t(m.frame_count()) - 1));
    clip.pause();
    clip.seek(m.frames[clamped].time);
  }
}

void on_key(GLFWwindow* window, int key, int, int action, int) {
  if (ImGui::GetIO().WantCaptureKeyboard || action == GLFW_RELEASE) return;
  auto& ui = *static_cast<Ui*>(glfwGetWindowUserPointer(window));
  playback::Player& player = *ui.player;
  if (key == GLFW_KEY_SPACE) {
    player.clip(0).state() == stream::PlayState::Playing ? player.pause() : player.play();
  } else if (key == GLFW_KEY_RIGHT) {
    step_frames(player, 1);
  } else if (key == GLFW_KEY_LEFT) {
    step_frames(player, -1);
  } else if (key == GLFW_KEY_F) {
    ui.follow = true;
  } else if (key == GLFW_KEY_H) {
    ui.show_ui = !ui.show_ui;
  } else if (key == GLFW_KEY_ESCAPE) {
    glfwSetWindowShouldClose(window, GLFW_TRUE);
  }
}

void cache_view(const stream::ParticleStream& clip) {
  const stream::DebugInfo d = clip.debug();
  const float block = 14.0f, gap = 2.0f;
  const int per_row = std::max(1, int((ImGui::GetContentRegionAvail().x + gap) / (block + gap)));
  ImDrawList* draw = ImGui::GetWindowDrawList();
  const ImVec2 origin = ImGui::GetCursorScreenPos();
  for (std::size_t i = 0; i < d.slots.size(); ++i) {
    const float x = origin.x + float(int(i) % per_row) * (block + gap),
                y = origin.y + float(int(i) / per_row) * (block + gap);
    const ImU32 colour = d.slots[i].state == stream::SlotState::Ready     ? IM_COL32(70, 190, 90, 255)
                         : d.slots[i].state == stream::SlotState::Loading ? IM_COL32(230, 180, 40, 255)
                                                                          : IM_COL32(70, 70, 80, 255);
    draw->AddRectFilled({x, y}, {x + block, y + block}, colour, 2.0f);
    if (i == d.read_slot && clip.frame().valid)
      draw->AddRect({x - 1, y - 1}, {x + block + 1, y + block + 1}, IM_COL32_WHITE, 2, 0, 2);
    if (ImGui::IsMouseHoveringRect({x, y}, {x + block, y + block})) {
      ImGui::SetTooltip("slot %zu: chunk %lld, %s", i, static_cast<long long>(d.slots[i].chunk),
                        d.slots[i].state == stream::SlotState::Ready     ? "Ready"
                        : d.slots[i].state == stream::SlotState::Loading ? "Loading"
                                                                         : "Empty");
    }
  }
  const int rows = (int(d.slots.size()) + per_row - 1) / per_row;
  ImGui::Dummy({1, float(rows) * (block + gap)});
  ImGui::TextWrapped(
      "%zu slots, %.1f MiB | loads %llu, in flight %u | read %.1f MiB, IO %.0f ms, decode %.0f ms | stalls %llu",
      d.slots.size(), d.cache_bytes / 1048576.0, static_cast<unsigned long long>(d.loads_done), d.loads_in_flight,
      d.bytes_read / 1048576.0, d.io_ms, d.decode_ms, static_cast<unsigned long long>(d.stalls));
  if (d.source.requests != 0) {  // a remote clip: what went over the wire
    ImGui::TextWrapped(
        "remote: %llu requests (%llu retried, %llu reads merged), %.1f MB, first byte %.0f ms, %.1f MB/s, %u in flight",
        static_cast<unsigned long long>(d.source.requests), static_cast<unsigned long long>(d.source.retries),
        static_cast<unsigned long long>(d.source.merged), d.source.bytes / 1e6, d.source.latency_ms,
        d.source.bandwidth_mb_s, d.source.in_flight);
  }
  ImGui::TextColored({0.45f, 0.75f, 0.5f, 1}, "Ready");
  ImGui::SameLine();
  ImGui::TextColored({0.9f, 0.7f, 0.15f, 1}, "Loading");
  ImGui::SameLine();
  ImGui::TextColored({0.5f, 0.5f, 0.55f, 1}, "Empty");
  ImGui::SameLine();
  ImGui::TextDisabled("(outline: current)");
}

}  // namespace

int run_viewer(const ViewerCli& cli) {
  glfwSetErrorCallback([](int, const char*) {});
  if (!glfwInit()) {
    throw Error("no display to open a window on (is DISPLAY set?). `pstream render FILE --out DIR` renders headless");
  }
  struct Terminate {
    ~Terminate() { glfwTerminate(); }
  } terminate;
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  GLFWwindow* window = glfwCreateWindow(cli.width, cli.height, "ParticleStream", nullptr, nullptr);
  if (window == nullptr) {
    throw Error(
        "could not create an OpenGL 4.5 core window: the driver or display lacks OpenGL 4.5. "
        "`pstream render FILE --out DIR` renders headless instead");
  }
  glfwMakeContextCurrent(window);
  glfwSwapInterval(cli.frames_to_run > 0 ? 0 : 1);

  std::vector<std::filesystem::path> files(cli.files.begin(), cli.files.end());
  playback::PlayerOptions options;  // loops by default
  options.path = playback::parse_playback_path(cli.playback);
  // A scripted run (--frames-to-run) shows each step's own frame, as `pstream render` does: its
  // streams decode in the host thread, so a busy machine cannot leave a screenshot without its
  // particles (the IO worker not done yet) or on another frame.
  options.stream.blocking = cli.frames_to_run > 0;
  const auto player = playback::Player::open(files, std::move(options));
  player->play();
  render::RendererOptions ro;
  ro.max_bytes_per_frame = std::max<std::uint64_t>(player->max_frame_bytes(), 4096);
  auto renderer = std::make_unique<render::Renderer>(ro);  // destroyed before its context (below)
  playback::DrawStyle style =
      cli.sprite_look.preset.empty() ? playback::DrawStyle{} : playback::look_preset(cli.sprite_look.preset);
  if (!cli.look.empty()) style.look = render::parse_look(cli.look);
  apply_look(cli.sprite_look, style);
  player->check_style(style);
  auto_ramp_range(cli.sprite_look, style, files);

  Ui ui;
  ui.look = style.look == render::Look::Liquid ? 1 : 0;
  ui.blend = style.blend == render::BlendMode::Alpha ? 0 : style.blend == render::BlendMode::Additive ? 1 : 2;
  ui.backdrop = playback::wants_ground(style);
  ui.player = player.get();
  ui.show_ui = !cli.hide_ui;
  int window_width = 0, window_height = 0;
  glfwGetWindowSize(window, &window_width, &window_height);
  ui.track = playback::framing_track(files, window_height > 0 ? float(window_width) / float(window_height) : 1.0f,
                                     free_region(window_width, window_height));
  ui.orbit.frame(ui.track.at(player->clip(0).time()));
  glfwSetWindowUserPointer(window, &ui);
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(window, true);
  ImGui_ImplOpenGL3_Init("#version 450");
  glfwSetKeyCallback(window, on_key);  // after ImGui's, which it chains

  double last = glfwGetTime();
  double stream_ms = 0, sort_ms = 0, draw_ms = 0, interpolate_ms = 0;
  std::size_t unmatched = 0;
  int frame_number = 0;
  std::array<float, 4> panel_rect{}, timeline_rect{};
  while (!glfwWindowShouldClose(window)) {
    glfwPollEvents();
    const double now = glfwGetTime();
    const double dt = cli.frames_to_run > 0 ? 1.0 / 30.0 : now - last;  // scripted runs step evenly
    last = now;

    // Camera: left drag orbits, right drag pans, the wheel zooms.
    ImGuiIO& io = ImGui::GetIO();
    if (!io.WantCaptureMouse) {
      double x, y;
      glfwGetCursorPos(window, &x, &y);
      const bool left = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
      const bool right = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS;
      if (left && ui.dragging_left) {
        ui.orbit.yaw -= float(x - ui.last_x) * 0.005f;
        ui.orbit.pitch = std::clamp(ui.orbit.pitch + float(y - ui.last_y) * 0.005f, -1.5f, 1.5f);
      }
      if (right && ui.dragging_right) {
        const render::Camera c = ui.orbit.camera();
        const render::Mat4 v = c.view();
        const float k = ui.orbit.distance * 0.0015f;
        for (int i = 0; i < 3; ++i)
          ui.orbit.target[i] += (-float(x - ui.last_x) * v[i * 4] + float(y - ui.last_y) * v[i * 4 + 1]) * k;
      }
      if ((left && ui.dragging_left) || (right && ui.dragging_right) || io.MouseWheel != 0) ui.follow = false;
      ui.dragging_left = left;
      ui.dragging_right = right;
      ui.last_x = x;
      ui.last_y = y;
      if (io.MouseWheel != 0) ui.orbit.distance *= std::pow(0.9f, io.MouseWheel);
    }

    int width = 0, height = 0;
    glfwGetFramebufferSize(window, &width, &height);
    if (ui.follow) ui.orbit.frame(ui.track.at(player->clip(0).time()));
    const render::Camera camera = ui.orbit.camera();
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    renderer->begin_frame(width, height, camera, {ui.background[0], ui.background[1], ui.background[2], 1});
    style.blend = ui.blend == 0   ? render::BlendMode::Alpha
                  : ui.blend == 1 ? render::BlendMode::Additive
                                  : render::BlendMode::AlphaTest;
    style.size_multiplier = ui.size;
    style.look = ui.look == 1 ? render::Look::Liquid : render::Look::Sprites;
    constexpr render::LiquidFilter kFilters[] = {render::LiquidFilter::NarrowRange, render::LiquidFilter::Bilateral,
                                                 render::LiquidFilter::Gaussian, render::LiquidFilter::None};
    constexpr render::LiquidOutput kOutputs[] = {render::LiquidOutput::Shaded, render::LiquidOutput::Depth,
                                                 render::LiquidOutput::Normals, render::LiquidOutput::Thickness};
    style.liquid.filter = kFilters[ui.liquid_filter];
    style.liquid.output = kOutputs[ui.liquid_output];
    if (ui.backdrop) {
      const auto& b = player->clip(0).metadata().bounds;
      style.backdrop = render::Backdrop::under({b[0], b[1], b[2]}, {b[3], b[4], b[5]});
    } else {
      style.backdrop.reset();
    }
    const sort::SortMode mode = ui.sort_mode == 0   ? sort::SortMode::None
                                : ui.sort_mode == 1 ? sort::SortMode::BackToFront
                                                    : sort::SortMode::FrontToBack;
    // The library's playback layer: every clip advanced, sorted (several clips together, so where
    // they overlap they blend in depth order) and drawn.
    player->set_speed(ui.speed);
    const playback::SortPlan plan = playback::sort_plan(style, camera.view(), renderer->light_direction(), mode);
    const playback::FrameStats& frame = player->advance(dt, plan.view, plan.mode);
    const auto t_draw0 = Clock::now();
    renderer->draw(player->draw_data(style));
    const double t_draw = std::chrono::duration<double, std::milli>(Clock::now() - t_draw0).count();
    const double t_stream = frame.stream_ms, t_sort = frame.sort_ms;
    const std::uint64_t drawn = frame.particles;
    renderer->end_frame();
    stream_ms = stream_ms * 0.9 + t_stream * 0.1;
    sort_ms = sort_ms * 0.9 + t_sort * 0.1;
    interpolate_ms = interpolate_ms * 0.9 + frame.interpolate_ms * 0.1;
    unmatched = frame.unmatched_clips;
    draw_ms = draw_ms * 0.9 + t_draw * 0.1;

    ImGui_ImplOpenGL3_NewFrame();
    ImGui_ImplGlfw_NewFrame();
    // Hidden (--hide-ui, H): laid out as ever but drawn fully transparent, so the picture is the
    // clip's alone and the panel's rectangle is still known.
    ImGui::GetStyle().Alpha = ui.show_ui ? 1.0f : 0.0f;
    ImGui::NewFrame();
    // A narrow, translucent panel: a quarter of a 1280-pixel window at most, labels that fit,
    // the longer explanations in tooltips.
    ImGui::SetNextWindowPos({kPanelX, 10}, ImGuiCond_FirstUseEver);
    ImGui::SetNextWindowSize({kPanelWidth, 0}, ImGuiCond_FirstUseEver);
    ImGui::SetNextWindowBgAlpha(0.72f);
    ImGui::Begin("ParticleStream");
    panel_rect = {ImGui::GetWindowPos().x, ImGui::GetWindowPos().y, ImGui::GetWindowSize().x, ImGui::GetWindowSize().y};
    ImGui::PushItemWidth(-110.0f);  // the widgets leave 110 pixels for their labels
    const auto tip = [](const char* text) {
      if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", text);
    };
    if (ImGui::Button("Play")) player->play();
    ImGui::SameLine();
    if (ImGui::Button("Pause")) player->pause();
    ImGui::SameLine();
    if (ImGui::Button("Stop")) player->stop();
    ImGui::SameLine();
    if (ImGui::Checkbox("Loop", &ui.loop)) player->set_loop(ui.loop);
    ImGui::Checkbox("Follow the effect", &ui.follow);
    if (ImGui::IsItemHovered())
      ImGui::SetTooltip("The camera of `pstream render`: it pulls back as the effect grows (F)");
    {
      auto& first = player->clip(0);
      const auto& m = first.metadata();
      float t = float(first.time());
      const float t0 = m.frame_count() ? float(m.frames.front().time) : 0,
                  t1 = m.frame_count() ? float(m.frames.back().time) : 0;
      if (ImGui::SliderFloat("Time", &t, t0, t1, "%.3f s")) player->seek(t);
    }
    ImGui::SliderFloat("Speed", &ui.speed, -2.0f, 4.0f, "%.2fx");  // below 0: backwards
    ImGui::SliderFloat("Particle size", &ui.size, 0.1f, 5.0f, "%.2fx");
    ImGui::Combo("Sort", &ui.sort_mode, "None\0Back to front\0Front to back\0");
    ImGui::Combo("Look", &ui.look, "Sprites\0Liquid\0");
    if (ui.look == 0) ImGui::Combo("Blend", &ui.blend, "Alpha\0Additive\0Alpha test\0");
    ImGui::Checkbox("Sky and ground grid", &ui.backdrop);
    ImGui::SameLine();
    ImGui::Checkbox("Bounds box", &style.bounds_box);
    if (ui.look == 0 && ImGui::TreeNodeEx("Sprites", ImGuiTreeNodeFlags_DefaultOpen)) {
      render::SpriteStyle& sp = style.sprites;
      ImGui::Checkbox("Shadows", &sp.shadows);
      tip("Self-shadowing by half-angle slices, and shadows on the ground");
      if (sp.shadows) {
        ImGui::SliderInt("Slices", &sp.slices, 1, 128);
        ImGui::SliderFloat("Shadow density", &sp.shadow_density, 0.0f, 4.0f, "%.2f");
      }
      int color_by = static_cast<int>(sp.color_by);
      if (ImGui::Combo("Colour", &color_by, "Stored\0Speed ramp\0Attribute ramp\0"))
        sp.color_by = static_cast<render::ColorBy>(color_by);
      if (sp.color_by != render::ColorBy::Stored)
        ImGui::DragFloatRange2("Ramp range", &sp.ramp.low, &sp.ramp.high, 0.05f);
      ImGui::Checkbox("Lit", &sp.lit);
      tip("Key, fill and rim light on each sprite");
      bool tinted = style.clip_tints[1] != playback::DrawStyle::white_tints()[1];
      if (player->clip_count() > 1 && ImGui::Checkbox("Tint each clip", &tinted))
        style.clip_tints = tinted ? playback::DrawStyle::distinct_tints() : playback::DrawStyle::white_tints();
      ImGui::SliderFloat("Opacity", &sp.opacity, 0.0f, 1.0f, "%.2f");
      ImGui::SliderFloat("Motion blur", &sp.shutter, 0.0f, 0.1f, "%.3f s");
      tip("Shutter: seconds of motion each sprite is stretched along (0: off)");
      ImGui::SliderFloat("Exposure", &sp.exposure, 0.1f, 8.0f, "%.2f", ImGuiSliderFlags_Logarithmic);
      ImGui::SliderFloat("Bloom", &sp.bloom, 0.0f, 1.0f, "%.2f");
      tip("Share of the light that spreads into a glow around it (the total is kept)");
      if (sp.bloom > 0.0f) ImGui::SliderFloat("Bloom radius", &sp.bloom_radius, 0.002f, 0.1f, "%.3f");
      bool filmic = sp.tone_map == render::ToneMap::Filmic;
      if (ImGui::Checkbox("Filmic tone map", &filmic))
        sp.tone_map = filmic ? render::ToneMap::Filmic : render::ToneMap::Linear;
      ImGui::TreePop();
    }
    if (ui.look == 1 && ImGui::TreeNodeEx("Liquid", ImGuiTreeNodeFlags_DefaultOpen)) {
      render::LiquidStyle& l = style.liquid;
      ImGui::Combo("Filter", &ui.liquid_filter, "Narrow range\0Bilateral\0Gaussian\0None\0");
      ImGui::Combo("Show", &ui.liquid_output, "Shaded\0Depth\0Normals\0Thickness\0");
      ImGui::SliderFloat("Smoothing", &l.smoothing, 0.0f, 12.0f, "%.1f r");
      tip("The filter's width, in particle radii");
      ImGui::SliderInt("Filter passes", &l.iterations, 0, 8);
      ImGui::SliderFloat("Resolution", &l.resolution, 0.25f, 1.0f, "%.2f");
      ImGui::ColorEdit3("Colour", l.color.data());
      ImGui::SliderFloat("Colour depth", &l.color_depth, 1.0f, 100.0f, "%.0f r", ImGuiSliderFlags_Logarithmic);
      tip("How deep the liquid is before it takes its full colour, in particle radii");
      ImGui::SliderFloat("Opacity depth", &l.opacity_depth, 0.0f, 20.0f, "%.1f r");
      tip("Liquid this thick (particle radii) hides most of what is behind it; 0: clear as glass");
      ImGui::SliderFloat("Refraction", &l.refraction, 0.0f, 4.0f, "%.2f");
      ImGui::SliderFloat("Shadow depth", &l.shadow_depth, 0.0f, 40.0f, "%.1f r");
      tip("The shadow on the ground: this much liquid along the light (particle radii) darkens it by 63 % of "
          "its strength; 0: none");
      ImGui::SliderFloat("Shadow strength", &l.shadow_strength, 0.0f, 1.0f, "%.2f");
      tip("How dark the ground gets under deep liquid (0.5 halves its light)");
      ImGui::SliderFloat("Spray: thin", &l.foam_isolation, 0.0f, 10.0f, "%.1f r");
      tip("Particles in liquid thinner than this many radii are drawn as spray");
      ImGui::SliderFloat("Spray: fast", &l.foam_speed, 0.0f, 20.0f, "%.1f u/s");
      tip("Particles faster than this (units per second) are drawn as spray");
      ImGui::TreePop();
    }
    ImGui::ColorEdit3("Background", ui.background);
    ImGui::Separator();
    ImGui::Text("%.0f fps | %llu particles drawn", ImGui::GetIO().Framerate, static_cast<unsigned long long>(drawn));
    // Host-thread times; on the GPU path interpolation and sorting run in the draw's compute passes.
    ImGui::Text("stream %.3f ms | interpolate %.3f ms", stream_ms, interpolate_ms);
    ImGui::Text("sort %.3f ms | upload + draw %.3f ms", sort_ms, draw_ms);
    if (player->path() == playback::PlaybackPath::Gpu) ImGui::TextDisabled("GPU path: interpolate + sort in the draw");
    if (unmatched != 0) {
      ImGui::PushTextWrapPos(0.0f);
      ImGui::TextDisabled("%zu clip(s) between unmatched frames: nearest frame shown", unmatched);
      ImGui::PopTextWrapPos();
    }
    ImGui::TextDisabled("%s", render::Renderer::gl_renderer().c_str());
    for (std::size_t i = 0; i < player->clip_count(); ++i) {
      const stream::ParticleStream& clip = player->clip(i);
      ImGui::Separator();
      const auto f = clip.frame();
      ImGui::Text("%s - frame %llu / %llu", files[i].filename().c_str(), static_cast<unsigned long long>(f.frame),
                  static_cast<unsigned long long>(clip.metadata().frame_count()));
      if (clip.state() == stream::PlayState::Error) {  // wrapped: the whole message, not its first line
        ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1, 0.35f, 0.3f, 1));
        ImGui::PushTextWrapPos(0.0f);
        ImGui::TextUnformatted(("error: " + clip.error()).c_str());
        ImGui::PopTextWrapPos();
        ImGui::PopStyleColor();
      }
      cache_view(clip);
    }
    ImGui::PushTextWrapPos(0.0f);
    ImGui::TextDisabled("space play/pause, arrows step, F follow the effect, drag orbit/pan, wheel zoom");
    ImGui::PopTextWrapPos();
    ImGui::PopItemWidth();
    ImGui::End();
    {  // The timeline along the bottom, in the source's frame numbers (the first clip's frames).
      const stream::ParticleStream& first = player->clip(0);
      const auto& m = first.metadata();
      const ImVec2 size = ImGui::GetIO().DisplaySize;
      ImGui::SetNextWindowPos({0, size.y - kTimelineHeight});
      ImGui::SetNextWindowSize({size.x, kTimelineHeight});
      ImGui::Begin("Timeline", nullptr,
                   ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoSavedSettings |
                       ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoBringToFrontOnFocus);
      timeline_rect = {ImGui::GetWindowPos().x, ImGui::GetWindowPos().y, ImGui::GetWindowSize().x,
                       ImGui::GetWindowSize().y};
      const stream::FrameView shown = first.frame();
      int frame = shown.valid ? int(shown.frame) : 0;
      const int last = m.frame_count() ? int(m.frame_count()) - 1 : 0;
      // A ramp's legend at the timeline's right end, where it never covers the clip: the ramp's
      // colours over its range, and what it measures.
      const render::SpriteStyle& sp = style.sprites;
      const bool legend = ui.look == 0 && sp.color_by != render::ColorBy::Stored;
      constexpr float kLegendWidth = 300;
      ImGui::SetNextItemWidth(size.x - 20 - (legend ? kLegendWidth + 10 : 0.0f));
      if (ImGui::SliderInt("##frame", &frame, 0, last, "frame %d") && m.frame_count())
        player->seek(m.frames[std::size_t(frame)].time);
      if (legend) {
        ImGui::SameLine();
        const std::string low = fmt::format("{:.3g}", sp.ramp.low);
        const std::string high = fmt::format(
            "{:.3g} {}", sp.ramp.high,
            sp.color_by == render::ColorBy::Speed ? std::string("units/s") : cli.sprite_look.ramp_attribute);
        ImGui::TextUnformatted(low.c_str());
        ImGui::SameLine();
        const float bar = kLegendWidth - ImGui::CalcTextSize(low.c_str()).x - ImGui::CalcTextSize(high.c_str()).x - 16;
        const ImVec2 at = ImGui::GetCursorScreenPos();
        const float h = ImGui::GetTextLineHeight();
        ImDrawList* draw = ImGui::GetWindowDrawList();
        constexpr int kSteps = 24;
        const auto colour = [&](int k) {  // linear RGB, shown with the sRGB curve's 1/2.2 power
          const auto c = sp.ramp.at(sp.ramp.low + (sp.ramp.high - sp.ramp.low) * float(k) / kSteps);
          return IM_COL32(int(255 * std::pow(std::clamp(c[0], 0.0f, 1.0f), 1 / 2.2f)),
                          int(255 * std::pow(std::clamp(c[1], 0.0f, 1.0f), 1 / 2.2f)),
                          int(255 * std::pow(std::clamp(c[2], 0.0f, 1.0f), 1 / 2.2f)), 255);
        };
        for (int k = 0; k < kSteps; ++k) {
          const float x0 = at.x + bar * float(k) / kSteps, x1 = at.x + bar * float(k + 1) / kSteps;
          draw->AddRectFilledMultiColor({x0, at.y}, {x1, at.y + h}, colour(k), colour(k + 1), colour(k + 1), colour(k));
        }
        ImGui::Dummy({bar, h});
        ImGui::SameLine();
        ImGui::TextUnformatted(high.c_str());
      }
      ImGui::End();
    }
    ImGui::Render();
    ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());

    ++frame_number;
    if (cli.frames_to_run > 0 && frame_number >= cli.frames_to_run) {
      // Where the panel and the timeline are (x y width height, window pixels), for scripts.
      fmt::print("panel {:.0f} {:.0f} {:.0f} {:.0f}\ntimeline {:.0f} {:.0f} {:.0f} {:.0f}\n", panel_rect[0],
                 panel_rect[1], panel_rect[2], panel_rect[3], timeline_rect[0], timeline_rect[1], timeline_rect[2],
                 timeline_rect[3]);
      if (!cli.screenshot.empty()) {
        std::vector<std::uint8_t> pixels(std::size_t(width) * height * 4);
        glPixelStorei(GL_PACK_ALIGNMENT, 1);
        glReadBuffer(GL_BACK);
        glReadPixels(0, 0, width, height, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
        const std::size_t row = std::size_t(width) * 4;
        for (int y = 0; y < height / 2; ++y) {
          std::swap_ranges(pixels.begin() + y * row, pixels.begin() + (y + 1) * row,
                           pixels.begin() + (height - 1 - y) * row);
        }
        render::write_png(cli.screenshot, width, height, pixels);
      }
      break;
    }
    glfwSwapBuffers(window);
  }
  renderer.reset();
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  glfwDestroyWindow(window);
  player->check();  // a clip that failed while playing makes the run fail too (scripts and tests see it)
  return 0;
}

}  // namespace pstream::app
