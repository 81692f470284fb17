"""A greedy planner that takes its time, so a sim mission lasts long enough to be watched."""

from pydantic import BaseModel, ConfigDict

from guadal_cli.planners.greedy import GreedyStd


class Config(BaseModel):
    model_config = ConfigDict(extra="forbid")
    delay_s: float = 0.25


class SlowGreedy(GreedyStd):
    Config = Config

    def next_targets(self, observation):
        import time

        time.sleep(self.config.delay_s)
        return super().next_targets(observation)
