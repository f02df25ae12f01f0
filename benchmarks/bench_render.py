"""Speed of the weather world: world build, rendering, weather, and the whole dataset stage.

Renders training poses of each condition of the default config (``conf/``) after a warm-up
(numba compiles on the first call), and prints milliseconds per frame for the renderer
(G-buffer) and the weather/camera model, and frames per second of both together, at the
stored 64x64 size with and without 2x super-sampling, for 1 and 2 threads. CPU time is printed
beside wall time (more telling on a shared machine). ``--dataset`` also times the dataset stage
on the default config (writes into ``benchmarks/out/dataset``).

    /work/venv/bin/python benchmarks/bench_render.py [--frames 256] [--threads 1 2] [--dataset]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numba

from cmal_lcd.config import REPO_ROOT, compose
from cmal_lcd.data.world import DataConfig, build_world, make_renderer, plan_train
from cmal_lcd.data.world.weather import apply_weather


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=256, help="frames per condition")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--dataset", action="store_true", help="also time the dataset stage")
    args = parser.parse_args()

    cfg = compose()
    config = DataConfig.from_config(cfg.data)
    world, build_s, _ = timed(lambda: build_world(config, seed=int(cfg.seed)))
    print(f"world build: {build_s:.2f} s ({world.n_cells}^2 cells, {len(world.sprites)} sprites)")
    sized = dataclasses.replace(config, train_per_condition=args.frames)
    groups = plan_train(sized, world, seed=int(cfg.seed))

    for supersample in (2, 1):
        h, w = (v * supersample for v in config.image_size)
        renderer = make_renderer(config.renderer, world, config.camera, image_size=(h, w))
        for group in groups:  # compile every kernel (rain streaks, lens drops) before timing
            warm = group.weather.subset(slice(0, 2))
            gbuf = renderer.render(group.poses.x[:2], group.poses.y[:2], group.poses.heading[:2],
                                   sun_direction=warm.sun_direction())
            apply_weather(gbuf, warm, supersample=supersample, sky_distance_m=350.0)
        for threads in args.threads:
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            for group in groups:
                render_s = weather_s = render_cpu = weather_cpu = 0.0
                for start in range(0, len(group), args.batch_size):
                    idx = slice(start, start + args.batch_size)
                    weather = group.weather.subset(idx)
                    gbuf, wall, cpu = timed(lambda: renderer.render(
                        group.poses.x[idx], group.poses.y[idx], group.poses.heading[idx],
                        sun_direction=weather.sun_direction()))
                    render_s, render_cpu = render_s + wall, render_cpu + cpu
                    _, wall, cpu = timed(lambda: apply_weather(
                        gbuf, weather, supersample=supersample,
                        sky_distance_m=config.camera.max_distance_m))
                    weather_s, weather_cpu = weather_s + wall, weather_cpu + cpu
                n = len(group)
                print(f"{config.image_size[0]}x{config.image_size[1]} ss={supersample} "
                      f"threads={threads} {group.condition:>6}: render {1e3 * render_s / n:5.2f} "
                      f"ms (cpu {1e3 * render_cpu / n:5.2f}), weather {1e3 * weather_s / n:5.2f} "
                      f"ms (cpu {1e3 * weather_cpu / n:5.2f}), "
                      f"{n / (render_s + weather_s):6.1f} frames/s")

    if args.dataset:
        from cmal_lcd.stages import make_dataset

        out = REPO_ROOT / "benchmarks" / "out" / "dataset"
        numba.set_num_threads(1)
        _, wall, cpu = timed(lambda: make_dataset.main(cfg, out_dir=Path(out)))
        print(f"dataset stage (default config, runtime.threads={cfg.runtime.threads}): "
              f"{wall:.1f} s wall, {cpu:.1f} s cpu")


if __name__ == "__main__":
    main()
