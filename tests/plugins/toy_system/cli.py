"""The toy system's own command, `mocapflow toy-walk`: the noiseless walk as CSV (frame, x), added to the command
line by the system's declaration (``commands``)."""

from __future__ import annotations

import click

FPS = 30.0


@click.command("toy-walk")
@click.option("--frames", default=5, show_default=True, type=click.IntRange(min=1))
@click.option("--speed", default=1.0, show_default=True, help="metres per second along x")
def toy_walk(frames: int, speed: float) -> None:
    """The toy marker's true positions along x, one line per frame."""
    click.echo("frame,x")
    for frame in range(frames):
        click.echo(f"{frame},{frame / FPS * speed:.6f}")
