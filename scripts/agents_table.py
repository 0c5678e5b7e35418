"""The shipped agents as a markdown table (from their model cards): task, algorithm, seeds, steps,
which policy ships (the last, or the best on the fixed evaluation plants: "start" = the starting
policy, i.e. the base controller), training wall time per seed (trained two at a time on the 2-core
machine), and the cards' notes.

    python scripts/agents_table.py
"""
import json

from millvib_env._paths import agents_dir
from millvib_env.catalog.agents import agent_seed_folders, list_agents


def _shipped(selected: dict) -> str:
    """Which policy a card ships: a training checkpoint (its steps; "start" for the starting policy) or a
    distilled student's iteration."""
    if "iteration" in selected:
        return f"iteration {selected['iteration']}"
    if "steps" in selected:  # `millvib finetune`: the steps at the score it kept
        return f"{selected['steps'] / 1e6:g} M"
    if "generation" in selected:  # scripts/es_output_layer.py
        return f"generation {selected['generation']}"
    return "start" if selected["timesteps"] == 0 else f"{selected['timesteps'] / 1e6:g} M"


def main() -> None:
    print("| agent | task | algorithm | env | seeds | steps per seed | shipped policy (per seed) | "
          "wall time per seed (min) | note |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in list_agents():
        cards = [json.loads((f / "card.json").read_text()) for f in agent_seed_folders(agents_dir() / name).values()]
        walls = [c["wall_time_s"] / 60 for c in cards]
        steps = sorted({round(c["n_timesteps"] / 1e6, 2) for c in cards})
        notes = sorted({c["note"] for c in cards if c.get("note")})
        shipped = ", ".join(_shipped(x["selected"]) for x in cards if x.get("selected")) or "last"
        c = cards[0]
        algo = ("DAgger (distill)" if "iteration" in c.get("selected", {})
                else "ppo (finetune)" if "steps" in c.get("selected", {})
                else "ES (output layer)" if "generation" in c.get("selected", {}) else c["algo"])
        if not notes and c.get("trained_by"):
            notes = [c["trained_by"]]
        print(f"| {name} | {c.get('task', 'startup')} | {algo} | {c['env_id'].replace('MillVib-', '')} | "
              f"{', '.join(str(x['seed']) for x in cards)} | {', '.join(f'{s:g} M' for s in steps)} | {shipped} | "
              f"{min(walls):.1f}-{max(walls):.1f} | {' '.join(notes)} |")


if __name__ == "__main__":
    main()
