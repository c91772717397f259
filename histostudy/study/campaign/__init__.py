"""The learned stages' training campaigns (docs/campaigns.md): a network trained over many steps, on
many machines, each step resumed from the last, measured on held-out frames as notebooks 02 and 03
measure the shipped networks, and recorded in the campaign's ledger (``data/campaigns/<name>/``).
"""

from ._compare import compare_restart_weights
from ._held_out import compare_held_out, evaluate_held_out
from ._ledger import ledger_table, read_ledger
from ._spec import CAMPAIGNS_DIR, CampaignSpec, load_campaign
from ._step import campaign_run_dir, run_campaign_step

__all__ = ["CAMPAIGNS_DIR", "CampaignSpec", "load_campaign", "run_campaign_step", "campaign_run_dir",
           "evaluate_held_out", "compare_held_out", "compare_restart_weights", "read_ledger", "ledger_table"]
