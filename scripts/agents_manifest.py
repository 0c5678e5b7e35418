"""Rewrite agents/MANIFEST.sha256 after adding or retraining a shipped agent.

    python scripts/agents_manifest.py
"""
from millvib_env.catalog.manifest import write_manifest

if __name__ == "__main__":
    print(f"wrote {write_manifest()}")
